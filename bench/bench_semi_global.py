"""Semi-global matching: stereodepth against OpenCV's StereoSGBM (MODE_SGBM_3WAY and MODE_HH)
on the shared scenes and on a 1280x720 pair, the numpy oracle on a crop, threads, instruction
sets, and how the time grows with W x H x D. Every benchmark checks the result it times.

    pytest bench/bench_semi_global.py

Both matchers get the same grey uint8 images, the same ndisp (16 * ceil((max GT + 1) / 16) on
the scenes, 128 on the 1280x720 pair) and 2 threads (cv2.setNumThreads(2)); StereoSGBM runs
with block 5, P1 = 8 * 25 and P2 = 32 * 25. The medians per group are printed as ratios to
stereodepth's (bench/conftest.py) with the time per pixel x disparity; the instruction set that
ran is in each benchmark's name (``stereodepth`` is the best this CPU runs).

On a shared machine the single-thread CPU time is the steadier figure:

    pytest bench/bench_semi_global.py -k "test_hd and 1-thread" --benchmark-timer=time.process_time
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth as sd
from stereodepth import reference
from stereodepth.io import read_image
from stereodepth.metrics import evaluate

THREADS = 2
ISA = str(sd.build_info()["isa"])


def data_dir() -> Path:
    env = os.environ.get("STEREODEPTH_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "stereo"


def scene_dirs() -> list[Path]:
    root = data_dir()
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if (p / "meta.json").is_file())


def to_grey(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return image
    rgb = image.astype(np.int32)  # OpenCV's COLOR_RGB2GRAY, bit for bit
    g = (rgb[..., 0] * 9798 + rgb[..., 1] * 19235 + rgb[..., 2] * 3735 + 16384) >> 15
    return g.astype(np.uint8)


_CACHE: dict[str, dict[str, Any]] = {}


def load_scene(path: Path) -> dict[str, Any]:
    if path.name not in _CACHE:
        meta = json.loads((path / "meta.json").read_text())
        mask_path = path / "mask_nonocc.npy"
        _CACHE[path.name] = {
            "name": path.name,
            "left": to_grey(read_image(path / "left.png")),
            "right": to_grey(read_image(path / "right.png")),
            "gt": np.load(path / "disp_gt.npy"),
            "mask": np.load(mask_path) if mask_path.is_file() else None,
            "ndisp": 16 * math.ceil((meta["max_disp"] + 1) / 16),
        }
    return _CACHE[path.name]


SCENES = scene_dirs()


def cv2_or_skip() -> Any:
    cv2 = pytest.importorskip("cv2")
    cv2.setNumThreads(THREADS)
    return cv2


def sgbm(cv2: Any, nd: int, mode_name: str) -> Any:
    mode = {"3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "hh": cv2.STEREO_SGBM_MODE_HH}[mode_name]
    return cv2.StereoSGBM_create(0, nd, 5, P1=8 * 25, P2=32 * 25, mode=mode)


def hd_pair(width: int = 1280, height: int = 720) -> tuple[np.ndarray, np.ndarray]:
    """A real pair at width x height: the largest shared scene, resized (or random dots shifted
    by 40 px when the scenes or OpenCV are missing)."""
    big = [p for p in SCENES if p.name == "mb2014q-adirondack"]
    try:
        import cv2
    except ImportError:
        cv2 = None
    if big and cv2 is not None:
        s = load_scene(big[0])
        size = (width, height)
        return (
            np.ascontiguousarray(cv2.resize(s["left"], size, interpolation=cv2.INTER_AREA)),
            np.ascontiguousarray(cv2.resize(s["right"], size, interpolation=cv2.INTER_AREA)),
        )
    rng = np.random.default_rng(0)
    canvas = rng.integers(0, 256, (height, width + 40)).astype(np.uint8)
    return np.ascontiguousarray(canvas[:, :width]), np.ascontiguousarray(canvas[:, 40:])


# ------------------------------------------------------------------------------------------
# The shared scenes: the default mode against SGBM 3WAY and HH


@pytest.mark.parametrize("impl_name", ["stereodepth", "opencv-sgbm-3way", "opencv-sgbm-hh"])
@pytest.mark.parametrize("scene_dir", SCENES, ids=[p.name for p in SCENES])
def test_scene(benchmark: Any, impl: Any, scene_dir: Path, impl_name: str) -> None:
    s = load_scene(scene_dir)
    left, right, nd = s["left"], s["right"], s["ndisp"]
    h, w = left.shape
    benchmark.group = f"sgm scene {s['name']} {w}x{h} ndisp={nd}"
    benchmark.extra_info["pixel_disparities"] = w * h * nd
    impl(impl_name)
    if impl_name == "stereodepth":
        matcher = sd.SemiGlobalMatcher(num_disparities=nd, threads=THREADS)
        d = benchmark(matcher.compute, left, right)
        np.testing.assert_array_equal(
            d, sd.semi_global_match(left, right, num_disparities=nd, threads=1)
        )
        assert evaluate(d, s["gt"], s["mask"]).bad_2 < 0.4
    else:
        cv2 = cv2_or_skip()
        raw = benchmark(sgbm(cv2, nd, impl_name.rsplit("-", 1)[1]).compute, left, right)
        assert raw.dtype == np.int16 and raw.shape == left.shape


# ------------------------------------------------------------------------------------------
# 1280x720, ndisp 128: the speed targets (the default paths=3 vs 3WAY, 8 paths vs HH), thread
# scaling and the instruction sets, one group per mode


HD_IMPLS = [
    "stereodepth",
    "stereodepth-1-thread",
    "stereodepth-baseline",
    "opencv-sgbm-3way",
    "opencv-sgbm-hh",
]


@pytest.mark.parametrize("impl_name", HD_IMPLS)
@pytest.mark.parametrize("paths", [3, 4, 8])
def test_hd(benchmark: Any, impl: Any, paths: int, impl_name: str) -> None:
    left, right = hd_pair()
    nd = 128
    h, w = left.shape
    benchmark.group = f"sgm {w}x{h} ndisp={nd} paths={paths} ({ISA})"
    benchmark.extra_info["pixel_disparities"] = w * h * nd
    impl(impl_name)
    if impl_name.startswith("stereodepth"):
        threads = 1 if impl_name.endswith("1-thread") else THREADS
        isa = "baseline" if impl_name.endswith("baseline") else "auto"
        matcher = sd.SemiGlobalMatcher(num_disparities=nd, paths=paths, threads=threads, isa=isa)
        d = benchmark.pedantic(matcher.compute, (left, right), rounds=5, warmup_rounds=1)
        assert np.isfinite(d).mean() > 0.5
        # Any thread count and instruction set: the same output, bit for bit.
        other = sd.SemiGlobalMatcher(
            num_disparities=nd, paths=paths, threads=3 - threads, isa="auto"
        ).compute(left, right)
        np.testing.assert_array_equal(d, other)
    else:
        cv2 = cv2_or_skip()
        m = sgbm(cv2, nd, impl_name.rsplit("-", 1)[1])
        raw = benchmark.pedantic(m.compute, (left, right), rounds=3, warmup_rounds=1)
        assert raw.shape == left.shape


# ------------------------------------------------------------------------------------------
# Cost against W x H x D (the default mode): ns per pixel x disparity stays flat


@pytest.mark.parametrize("nd", [64, 128, 256])
@pytest.mark.parametrize(
    "size", [(320, 240), (640, 480), (1280, 720)], ids=lambda s: f"{s[0]}x{s[1]}"
)
def test_scaling(benchmark: Any, impl: Any, size: tuple[int, int], nd: int) -> None:
    left, right = hd_pair(*size)
    w, h = size
    benchmark.group = f"sgm scaling {w}x{h} ndisp={nd}"
    benchmark.extra_info["pixel_disparities"] = w * h * nd
    impl("stereodepth")
    matcher = sd.SemiGlobalMatcher(num_disparities=nd, threads=THREADS)
    d = benchmark.pedantic(matcher.compute, (left, right), rounds=3, warmup_rounds=1)
    assert d.shape == (h, w)


# ------------------------------------------------------------------------------------------
# The oracle on a crop


@pytest.mark.parametrize("impl_name", ["stereodepth", "numpy-oracle"])
def test_oracle_crop(benchmark: Any, impl: Any, impl_name: str) -> None:
    left, right = hd_pair()
    left, right = (
        np.ascontiguousarray(left[300:360, 500:620]),
        np.ascontiguousarray(right[300:360, 500:620]),
    )
    benchmark.group = "sgm crop 120x60 ndisp=32"
    benchmark.extra_info["pixel_disparities"] = 120 * 60 * 32
    impl(impl_name)
    fn = sd.semi_global_match if impl_name == "stereodepth" else reference.semi_global_match
    d = benchmark.pedantic(fn, (left, right), {"num_disparities": 32}, rounds=3)
    np.testing.assert_allclose(
        d, sd.semi_global_match(left, right, num_disparities=32), atol=1e-3, equal_nan=True
    )


# ------------------------------------------------------------------------------------------
# The speed targets, interleaved: on a shared machine whose speed drifts from second to second,
# the ratio of two matchers is steadiest when their calls alternate and each round's ratio is
# taken (its median over the rounds is the figure; the ratio of the least times is printed
# beside it).


def test_speed_vs_sgbm_interleaved(alternate: Any) -> None:
    """Per scene and on the 1280 x 720 pair (ndisp 128): the default mode (paths=3) against
    SGBM 3WAY, the median over rounds of the time ratio (issue 11's target: at most 0.33), and
    paths=8 against MODE_HH (at most 0.2). Both matchers made once, 2 threads, the same grey
    images and ndisp.

        pytest bench/bench_semi_global.py -k interleaved -s
    """
    cv2 = cv2_or_skip()
    rounds = int(os.environ.get("STEREODEPTH_BENCH_ROUNDS", "11"))
    print()
    print(f"ISA: {ISA}, {THREADS} threads, {rounds} rounds")
    print(
        "| scene | W x H x ndisp | paths | stereodepth ms | OpenCV mode | OpenCV ms | ratio | "
        "least-time ratio | stereodepth ns/(px*d) |"
    )
    print("|---|---|---:|---:|---|---:|---:|---:|---:|")
    scenes = [load_scene(path) for path in SCENES]
    hd_left, hd_right = hd_pair()
    hd = {"name": "adirondack 1280x720", "left": hd_left, "right": hd_right, "ndisp": 128}
    cases = (
        [(s, 3, "3way") for s in scenes]
        + [(hd, 3, "3way")]
        + [(s, 8, "hh") for s in scenes]
        + [(hd, 8, "hh")]
    )
    scene_ratios: dict[str, list[float]] = {"3way": [], "hh": []}
    for s, paths, mode in cases:
        left, right, nd = s["left"], s["right"], s["ndisp"]
        h, w = left.shape
        ours = sd.SemiGlobalMatcher(num_disparities=nd, paths=paths, threads=THREADS)
        theirs = sgbm(cv2, nd, mode)
        want = ours.compute(left, right)
        theirs.compute(left, right)
        n = rounds if mode == "3way" else max(3, rounds // 3)
        mine, other = (
            np.asarray(t)
            for t in alternate(
                lambda m=ours, a=left, b=right: m.compute(a, b),
                lambda m=theirs, a=left, b=right: m.compute(a, b),
                n,
            )
        )
        np.testing.assert_array_equal(ours.compute(left, right), want)
        ratio = float(np.median(mine / other))
        least = float(mine.min() / other.min())
        if s is not hd:
            scene_ratios[mode].append(ratio)
        ns = 1e9 * float(np.median(mine)) / (w * h * nd)
        print(
            f"| {s['name']} | {w} x {h} x {nd} | {paths} | {1e3 * np.median(mine):.2f} | "
            f"{mode.upper()} | {1e3 * np.median(other):.2f} | {ratio:.3f} | "
            f"{least:.3f} | {ns:.3f} |"
        )
    for mode, paths, name in (("3way", 3, "SGBM 3WAY"), ("hh", 8, "SGBM HH")):
        if scene_ratios[mode]:
            print(
                f"median over the {len(scene_ratios[mode])} scenes of stereodepth "
                f"(paths={paths}) / {name}: {np.median(scene_ratios[mode]):.3f}"
            )


def test_after_idle() -> None:
    """Calls after an idle spell, as in a camera pipeline that matches a frame and then waits
    for the next: the median time per call back to back, after 50 ms of sleep (2 threads),
    and after the same sleep with one thread, for the block matcher and both modes.

    On a virtual machine the host takes idle vCPUs back, and the guest's kernel may then run a
    call's two threads on one CPU for milliseconds: a call after a pause can take the time of
    one thread (bench/README, twenty-fourth round).

        pytest bench/bench_semi_global.py -k after_idle -s
    """
    if not SCENES:
        pytest.skip("the shared scenes are absent")
    rounds = int(os.environ.get("STEREODEPTH_BENCH_ROUNDS", "11"))
    pause = 0.05
    print()
    print(f"ISA: {ISA}, {rounds} rounds, pause {1e3 * pause:.0f} ms")
    print("| scene | matcher | back to back ms | after a pause ms | 1 thread after a pause ms |")
    print("|---|---|---:|---:|---:|")
    by_name = {p.name: p for p in SCENES}
    for name in ("mb2001-tsukuba", "mb2003-cones"):
        if name not in by_name:
            continue
        s = load_scene(by_name[name])
        left, right, nd = s["left"], s["right"], s["ndisp"]
        for label, cls, extra in (
            ("block matcher", sd.StereoMatcher, {}),
            ("paths=3", sd.SemiGlobalMatcher, {}),
            ("paths=8", sd.SemiGlobalMatcher, {"paths": 8}),
        ):
            medians = []
            for threads, wait in ((THREADS, 0.0), (THREADS, pause), (1, pause)):
                m = cls(num_disparities=nd, threads=threads, **extra)
                want = m.compute(left, right)
                times = []
                for _ in range(rounds):
                    time.sleep(wait)
                    t0 = time.perf_counter()
                    got = m.compute(left, right)
                    times.append(time.perf_counter() - t0)
                np.testing.assert_array_equal(got, want)
                medians.append(1e3 * float(np.median(times)))
            print(f"| {name} | {label} | " + " | ".join(f"{v:.2f}" for v in medians) + " |")
