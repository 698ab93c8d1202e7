"""Small defects a new user met in the commands: a valid depth under half a millimetre written
as "no depth" (0) in the millimetre PNGs of ``match`` and ``batch``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PIL", reason="reading images needs Pillow (the batch extra)")

from PIL import Image

from stereodepth import cli, disparity_to_depth
from stereodepth.io import read_disparity_pfm, read_image
from stereodepth.sample import sample_pair

#: A rig so small that every depth of the sample pair is under half a millimetre (f B =
#: 300 px x 1 um: 0.03 mm at 10 px).
TINY_RIG = ["--focal-px", "300", "--baseline-mm", "0.001"]


def scenes(root: Path, n: int = 2) -> Path:
    """``n`` folders of a left/right sample pair, 96 x 64 px."""
    s = sample_pair(96, 64)
    for i in range(n):
        d = root / f"s{i}"
        d.mkdir(parents=True)
        Image.fromarray(s.left).save(d / "left.png")
        Image.fromarray(s.right).save(d / "right.png")
    return root


# --- 1. millimetre depth: a valid depth is never 0 --------------------------------------------
def test_match_png16_depth_of_a_near_scene_has_no_false_holes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pair = scenes(tmp_path / "in", 1) / "s0"
    out = tmp_path / "out"
    argv = ["match", str(pair / "left.png"), str(pair / "right.png"), *TINY_RIG]
    argv += ["--depth-format", "png16", "--no-preview", "-o", f"{out}/"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    d = read_disparity_pfm(out / "disparity.pfm")
    mm = read_image(out / "depth.png")
    valid = np.isfinite(d)
    assert valid.mean() > 0.5
    # Every depth here is under 0.05 mm: 1 mm (the least valid value) where there is one.
    assert np.array_equal(mm, np.where(valid, 1, 0).astype(np.uint16))
    want = disparity_to_depth(d, focal_px=300.0, baseline_m=1e-6, dtype=np.uint16)
    assert np.array_equal(mm, want)


def test_batch_png16_depth_of_a_near_scene_has_no_false_holes(tmp_path: Path) -> None:
    scenes(tmp_path / "in")
    out = tmp_path / "out"
    argv = ["batch", str(tmp_path / "in"), "-o", str(out), *TINY_RIG, "--num-disparities", "16"]
    assert cli.main([*argv, "--format", "png16", "--threads", "1", "--quiet"]) == 0
    for stem in ("s0", "s1"):
        raw = read_image(out / f"{stem}.disparity.png")
        mm = read_image(out / f"{stem}.depth.png")
        assert (raw > 0).mean() > 0.5
        assert np.array_equal(mm, np.where(raw > 0, 1, 0).astype(np.uint16))
