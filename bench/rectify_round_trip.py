"""Issue 14's round trip, per scene and per matcher: how much bad-2 a raw pair costs.

Each shared scene is made "raw" by the documented generator of
``tests/test_rectify_roundtrip.py`` (a synthetic Brown-Conrady lens and small rotations),
rectified back with ``StereoRectifier``, and matched; the original pair is matched too. The
table gives, per matcher, the original pair's bad-2 and the round trip's extra, in points
(non-occluded pixels where a mask exists, holes count as bad, pixels whose round trip leaves
either image left out, as in the test). OpenCV's SGBM 3WAY, plain and on the pair padded on
the left by D columns (as ``stereodepth eval`` runs them), are matched on the same images
when OpenCV is installed, to tell the rectifier's share from the matchers' sensitivity.

    PYTHONPATH=python python bench/rectify_round_trip.py [--data ../shared/data/stereo]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import stereodepth
from stereodepth.evaluation import num_disparities_for
from stereodepth.io import read_image
from stereodepth.metrics import evaluate
from stereodepth.rectify import StereoRectifier

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
import test_rectify_roundtrip as generator  # noqa: E402  (the documented generator)

Match = Callable[[np.ndarray, np.ndarray], np.ndarray]


def matchers(nd: int) -> dict[str, Match]:
    out: dict[str, Match] = {
        "semi-global": lambda lt, rt: stereodepth.semi_global_match(lt, rt, num_disparities=nd),
        "block matching": lambda lt, rt: stereodepth.block_match(lt, rt, num_disparities=nd),
    }
    try:
        import cv2
    except ImportError:
        return out

    def sgbm(pad: int) -> Match:
        m = cv2.StereoSGBM_create(
            minDisparity=0, numDisparities=nd, blockSize=5, P1=200, P2=800,
            mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
        )  # fmt: skip

        def run(left: np.ndarray, right: np.ndarray) -> np.ndarray:
            grey = [
                x if x.ndim == 2 else cv2.cvtColor(x, cv2.COLOR_RGB2GRAY) for x in (left, right)
            ]
            if pad:
                grey = [cv2.copyMakeBorder(x, 0, 0, pad, 0, cv2.BORDER_REPLICATE) for x in grey]
            raw = m.compute(*grey)[:, pad:]
            return stereodepth.from_opencv_disparity(raw, min_disparity=0)

        return run

    out["SGBM 3WAY"] = sgbm(0)
    out["SGBM 3WAY padded"] = sgbm(nd)
    return out


def scene_scores(path: Path) -> dict[str, tuple[float, float]]:
    meta = json.loads((path / "meta.json").read_text())
    left, right = read_image(path / "left.png"), read_image(path / "right.png")
    gt = np.load(path / "disp_gt.npy")
    mask_path = path / "mask_nonocc.npy"
    mask = np.load(mask_path) if mask_path.exists() else np.ones(gt.shape, bool)
    h, w = gt.shape
    raw_l, raw_r, calib, gen_maps = generator.make_raw_pair(left, right)
    rect = StereoRectifier.from_calibration(calib, threads=2)
    back_l, back_r = rect.rectify(raw_l, raw_r)
    white = np.full((h, w), 255, np.uint8)
    valid_l, _ = (
        img == 255 for img in rect.rectify(*(stereodepth.remap(white, *m) for m in gen_maps))
    )
    scored = mask & valid_l
    nd = num_disparities_for(meta["max_disp"])
    scores: dict[str, tuple[float, float]] = {}
    for name, match in matchers(nd).items():
        original = evaluate(match(left, right), gt, scored).bad_2
        round_trip = evaluate(match(back_l, back_r), gt, scored).bad_2
        scores[name] = (100 * original, 100 * (round_trip - original))
    return scores


def main(argv: Any = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "stereo")
    args = parser.parse_args(argv)
    scenes = [s for s in generator.SCENES if (args.data / s).is_dir()]
    if not scenes:
        parser.error(f"--data: no shared scene in {args.data}")
    rows = {s: scene_scores(args.data / s) for s in scenes}
    names = list(next(iter(rows.values())))
    print(f"ISA: {stereodepth.SemiGlobalMatcher(num_disparities=16).isa}; "
          "bad-2 of the original pair / round trip minus original, points")  # fmt: skip
    print("| scene | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for scene, scores in rows.items():
        cells = (f"{scores[n][0]:.2f} / {scores[n][1]:+.2f}" for n in names)
        print(f"| {scene} | " + " | ".join(cells) + " |")
    table = {n: np.array([rows[s][n] for s in scenes]) for n in names}
    means = (f"{t[:, 0].mean():.2f} / {t[:, 1].mean():+.2f}" for t in table.values())
    within = (f"{int((t[:, 1] <= 1).sum())} of {len(scenes)}" for t in table.values())
    print("| **mean** | " + " | ".join(means) + " |")
    print("| scenes within 1 point | " + " | ".join(within) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
