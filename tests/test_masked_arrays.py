"""A masked array (numpy.ma) handed to any public function is a TypeError naming the
parameter: nothing in the package reads a mask, so the masked elements were used as values,
silently (an evaluation scored the pixels the caller had masked out)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth as sd
from stereodepth import io as sio
from stereodepth.match_pair import prepare_pair
from stereodepth.metrics import evaluate
from stereodepth.semi_global import fill_background

rng = np.random.default_rng(5)
GREY = rng.integers(0, 256, (12, 40), dtype=np.uint8)
DISP = rng.uniform(1, 20, (12, 40)).astype(np.float32)
Q = np.array([[1, 0, 0, -20], [0, 1, 0, -6], [0, 0, 0, 700], [0, 0, 0.01, 0]], np.float64)
MAP_X, MAP_Y = (a.astype(np.float32) for a in np.meshgrid(np.arange(40), np.arange(12)))


def masked(a: np.ndarray) -> np.ma.MaskedArray:
    m = np.zeros(a.shape, bool)
    m.flat[0] = True
    return np.ma.masked_array(a.copy(), mask=m)


def rectifier() -> sd.StereoRectifier:
    K = np.array([[700.0, 0, 20], [0, 700, 6], [0, 0, 1]])
    return sd.StereoRectifier(
        K1=K, D1=np.zeros(5), K2=K, D2=np.zeros(5), R=np.eye(3), T=[-0.1, 0, 0], image_size=(40, 12)
    )


CASES: list[tuple[str, str, Callable[..., Any]]] = [
    ("block_match left", "left", lambda: sd.block_match(masked(GREY), GREY, num_disparities=8)),
    ("block_match right", "right", lambda: sd.block_match(GREY, masked(GREY), num_disparities=8)),
    (
        "StereoMatcher.compute",
        "left",
        lambda: sd.StereoMatcher(num_disparities=8).compute(masked(GREY), GREY),
    ),
    (
        "semi_global_match",
        "right",
        lambda: sd.semi_global_match(GREY, masked(GREY), num_disparities=8),
    ),
    (
        "SemiGlobalMatcher.compute",
        "left",
        lambda: sd.SemiGlobalMatcher(num_disparities=8).compute(masked(GREY), GREY),
    ),
    ("fill_background", "disparity", lambda: fill_background(masked(DISP))),
    ("prepare_pair", "left", lambda: prepare_pair(masked(GREY), GREY)),
    ("remap image", "image", lambda: sd.remap(masked(GREY), MAP_X, MAP_Y)),
    ("remap map", "map", lambda: sd.remap(GREY, masked(MAP_X), MAP_Y)),
    ("rectify", "left", lambda: rectifier().rectify(masked(GREY), GREY)),
    (
        "stereo_rectify K1",
        "K1",
        lambda: sd.stereo_rectify(
            masked(np.eye(3) * 700),
            np.zeros(5),
            np.eye(3) * 700,
            np.zeros(5),
            (40, 12),
            np.eye(3),
            [-0.1, 0, 0],
        ),
    ),
    ("evaluate disparity", "disparity", lambda: evaluate(masked(DISP), DISP)),
    ("evaluate gt", "gt", lambda: evaluate(DISP, masked(DISP))),
    ("evaluate mask", "mask", lambda: evaluate(DISP, DISP, mask=masked(np.ones((12, 40), bool)))),
    ("colorize", "values", lambda: sd.colorize(masked(DISP))),
    (
        "disparity_to_depth",
        "disparity",
        lambda: sd.disparity_to_depth(masked(DISP), focal_px=700, baseline_m=0.1),
    ),
    (
        "disparity_to_depth out",
        "out",
        lambda: sd.disparity_to_depth(
            DISP, focal_px=700, baseline_m=0.1, out=masked(np.zeros((12, 40), np.float32))
        ),
    ),
    ("reproject", "disparity", lambda: sd.reproject(masked(DISP), Q=Q)),
    (
        "reproject out",
        "out",
        lambda: sd.reproject(DISP, Q=Q, out=masked(np.zeros((12, 40, 3), np.float32))),
    ),
]


@pytest.mark.parametrize(("name", "param", "call"), CASES, ids=[c[0] for c in CASES])
def test_a_masked_array_is_refused(name: str, param: str, call: Callable[..., Any]) -> None:
    with pytest.raises(TypeError, match=rf"\b{param}\w* must not be a masked array"):
        call()


@pytest.mark.parametrize(
    "writer",
    [
        lambda p: sio.write_npy(p, masked(DISP)),
        lambda p: sio.write_pfm(p, masked(DISP)),
        lambda p: sio.write_disparity_png16(p, masked(DISP)),
        lambda p: sd.write_ply(p, masked(np.ones((4, 3), np.float32))),
    ],
    ids=["npy", "pfm", "png16", "ply"],
)
def test_a_masked_array_is_not_written(tmp_path: Path, writer: Callable[[Path], Any]) -> None:
    target = tmp_path / "out.bin"
    with pytest.raises(TypeError, match="must not be a masked array"):
        writer(target)
    assert not target.exists()
