"""Rectifying a 1920 x 1080 raw pair with prebuilt maps: StereoRectifier.rectify against
cv2.remap with its fastest maps (CV_16SC2 + interpolation table, from cv2.convertMaps) and
with float32 maps, both on 2 threads (cv2.setNumThreads(2)), and the numpy oracle. Each
benchmark checks its result.

    pytest bench/bench_rectify.py
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import reference
from stereodepth.rectify import StereoRectifier

W, H = 1920, 1080
THREADS = 2
K1 = np.array([[1400.0, 0, 962.5], [0, 1401.0, 541.0], [0, 0, 1]])
K2 = np.array([[1396.0, 0, 957.0], [0, 1397.5, 538.5], [0, 0, 1]])
D1 = np.array([-0.21, 0.06, 0.0012, -0.0009, -0.008])
D2 = np.array([-0.19, 0.05, -0.0007, 0.0011, -0.006])
T = np.array([-0.12, 0.0011, 0.0023])


def rotation(rvec: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(rvec))
    k = rvec / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * (kx @ kx)


@pytest.fixture(scope="module")
def rectifier() -> StereoRectifier:
    R = rotation(np.array([0.011, -0.018, 0.004]))
    return StereoRectifier(
        K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=(W, H), alpha=0.0, threads=THREADS
    )


@pytest.fixture(scope="module", params=["grey8", "rgb8"])
def case(request: Any, rectifier: StereoRectifier) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    shape = (H, W) if request.param == "grey8" else (H, W, 3)
    # A smooth scene plus noise: like a photograph, not like a checkerboard of extremes.
    yy, xx = np.mgrid[0:H, 0:W]
    base = 128 + 60 * np.sin(xx / 37.0) * np.cos(yy / 23.0)
    if len(shape) == 3:
        base = base[..., None] + np.array([0.0, 20.0, -20.0])
    left = np.clip(base + rng.normal(0, 20, shape), 0, 255).astype(np.uint8)
    right = np.clip(np.roll(base, -30, axis=1) + rng.normal(0, 20, shape), 0, 255)
    right = right.astype(np.uint8)
    maps = [rectifier.maps(side) for side in ("left", "right")]
    want = tuple(reference.remap(img, *m) for img, m in zip((left, right), maps, strict=True))
    return {"name": request.param, "left": left, "right": right, "maps": maps, "want": want}


def group(benchmark: Any, c: dict[str, Any]) -> None:
    benchmark.group = f"rectify a {W}x{H} {c['name']} pair, maps prebuilt, {THREADS} threads"
    benchmark.extra_info["isa"] = stereodepth.build_info()["isa"]


def test_stereodepth(benchmark: Any, impl: Any, case: dict[str, Any], rectifier: Any) -> None:
    group(benchmark, case)
    impl("stereodepth")
    outs = (np.empty_like(case["left"]), np.empty_like(case["right"]))
    benchmark(rectifier.rectify, case["left"], case["right"], out_left=outs[0], out_right=outs[1])
    for got, want in zip(outs, case["want"], strict=True):
        np.testing.assert_array_equal(got, want)


def test_stereodepth_one_thread(benchmark: Any, impl: Any, case: dict[str, Any]) -> None:
    group(benchmark, case)
    impl("stereodepth threads=1")
    one = StereoRectifier(
        K1=K1,
        D1=D1,
        K2=K2,
        D2=D2,
        R=rotation(np.array([0.011, -0.018, 0.004])),
        T=T,
        image_size=(W, H),
        alpha=0.0,
        threads=1,
    )
    got = benchmark(one.rectify, case["left"], case["right"])
    for g, want in zip(got, case["want"], strict=True):
        np.testing.assert_array_equal(g, want)


def opencv() -> Any:
    cv2 = pytest.importorskip("cv2", reason="OpenCV is not installed (the bench extra)")
    cv2.setNumThreads(THREADS)
    return cv2


def test_opencv_remap_16sc2(benchmark: Any, impl: Any, case: dict[str, Any]) -> None:
    cv2 = opencv()
    group(benchmark, case)
    impl("cv2.remap CV_16SC2 maps")
    fixed = [cv2.convertMaps(mx, my, cv2.CV_16SC2) for mx, my in case["maps"]]

    def run() -> tuple[np.ndarray, np.ndarray]:
        return (
            cv2.remap(case["left"], *fixed[0], cv2.INTER_LINEAR),
            cv2.remap(case["right"], *fixed[1], cv2.INTER_LINEAR),
        )

    got = benchmark(run)
    # OpenCV rounds positions to 1/32 px: a few grey levels from the float-map result.
    for g, want in zip(got, case["want"], strict=True):
        assert np.abs(g.astype(np.int16) - want).max() <= 8


def test_opencv_remap_float(benchmark: Any, impl: Any, case: dict[str, Any]) -> None:
    cv2 = opencv()
    group(benchmark, case)
    impl("cv2.remap float32 maps")

    def run() -> tuple[np.ndarray, np.ndarray]:
        return (
            cv2.remap(case["left"], *case["maps"][0], cv2.INTER_LINEAR),
            cv2.remap(case["right"], *case["maps"][1], cv2.INTER_LINEAR),
        )

    got = benchmark(run)
    for g, want in zip(got, case["want"], strict=True):
        assert np.abs(g.astype(np.int16) - want).max() <= 1


def test_oracle(benchmark: Any, impl: Any, case: dict[str, Any]) -> None:
    group(benchmark, case)
    impl("oracle (stereodepth.reference.remap)")

    def run() -> tuple[np.ndarray, np.ndarray]:
        return (
            reference.remap(case["left"], *case["maps"][0]),
            reference.remap(case["right"], *case["maps"][1]),
        )

    got = benchmark.pedantic(run, rounds=1, iterations=1)
    for g, want in zip(got, case["want"], strict=True):
        np.testing.assert_array_equal(g, want)
