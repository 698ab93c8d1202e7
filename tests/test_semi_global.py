"""stereodepth.semi_global_match / SemiGlobalMatcher against the numpy oracle, and its rules.

The oracle (stereodepth.reference.semi_global_match) follows the documented steps with full
(H, W, D) volumes; the kernel must agree exactly on integer disparities and validity, and
within 1e-3 px after the sub-pixel step. Images are small so the oracle stays fast.
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from synthetic_pairs import shifted_pair, slanted_pair

import stereodepth as sd
from stereodepth import reference as ref
from stereodepth._reference_block_match import grey
from stereodepth._reference_semi_global import median3
from stereodepth.io import read_image
from stereodepth.semi_global import run_disparities, stripe_starts

SUPPORTED_ISAS: list[str] = list(sd.build_info()["supported_isas"])


def step_pair(
    shape: tuple[int, int], near: int, far: int, *, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random-dot stereogram of a near square over a far background: the true disparity
    (NaN where the left pixel is occluded in the right image)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    right = rng.integers(0, 256, size=(h, w)).astype(np.uint8)
    left = np.empty_like(right)
    truth = np.full((h, w), np.nan, np.float32)
    xs = np.arange(w)
    y0, y1, x0, x1 = h // 4, 3 * h // 4, w // 3, 2 * w // 3
    square = rng.integers(0, 256, size=(h, w + near)).astype(np.uint8)
    for y in range(h):
        src = np.clip(xs - far, 0, w - 1)
        left[y] = right[y, src]
        truth[y] = np.where(xs - far >= 0, far, np.nan)
        if y0 <= y < y1:
            left[y, x0:x1] = square[y, x0:x1]
            truth[y, x0:x1] = near
            # the right image shows the square near px to the left
            right[y, x0 - near : x1 - near] = square[y, x0:x1]
    # left pixels whose background point is hidden behind the square in the right image
    for y in range(y0, y1):
        hidden = (xs - far >= x0 - near) & (xs - far < x1 - near) & ((xs < x0) | (xs >= x1))
        truth[y, hidden] = np.nan
    return left, right, truth


def assert_agree(native: Any, oracle: Any, *, subpixel: bool) -> None:
    """The same NaNs; equal disparities (within 1e-3 px after the sub-pixel step)."""
    if isinstance(oracle, tuple):
        assert isinstance(native, tuple)
        assert_agree(native[0], oracle[0], subpixel=subpixel)
        np.testing.assert_allclose(native[1], oracle[1], rtol=0, atol=1e-6)
        return
    assert native.dtype == np.float32
    assert native.shape == oracle.shape
    np.testing.assert_array_equal(np.isnan(native), np.isnan(oracle))
    if subpixel:
        np.testing.assert_allclose(native, oracle, rtol=0, atol=1e-3)
    else:
        np.testing.assert_array_equal(native, oracle)


CONFIGS: list[dict[str, Any]] = [
    {
        "subpixel": False,
        "uniqueness_ratio": 0,
        "lr_max_diff": None,
        "median": False,
        "speckle_window": 0,
    },
    {"subpixel": False},
    {},
    {"paths": 8, "return_confidence": True},
    {"block_size": 1, "p1": 3, "p2": 30, "subpixel": "equiangular"},
    {"p2_step": 0, "uniqueness_ratio": 15, "lr_max_diff": 0},
    {"border": "opencv", "paths": 8, "return_confidence": True},
    {"paths": 3, "return_confidence": True},
    {"fill": True, "return_confidence": True},
    {"p1": 0, "p2": 0, "median": False, "speckle_window": 20, "speckle_range": 0.5},
    {"p2_step": 1, "p1": 10, "p2": 2000, "lr_max_diff": 1.5, "return_confidence": True},
]


def config_id(cfg: dict[str, Any]) -> str:
    return ",".join(f"{k}={v}" for k, v in cfg.items()) or "defaults"


def subpixel_of(cfg: dict[str, Any]) -> bool:
    return cfg.get("subpixel", True) is not False


# ------------------------------------------------------------------------------------------
# Native against the oracle


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("cfg", CONFIGS, ids=config_id)
def test_random_dots_match_oracle(cfg: dict[str, Any], isa: str) -> None:
    left, right = shifted_pair((29, 71), 6, seed=1)
    left[5:15, 20:40] = 128  # flat: ties
    right[5:15, 14:34] = 128
    kw = {"num_disparities": 21, "min_disparity": -3, **cfg}
    native = sd.SemiGlobalMatcher(isa=isa, threads=2, **kw).compute(left, right)
    assert_agree(native, ref.semi_global_match(left, right, **kw), subpixel=subpixel_of(cfg))


@pytest.mark.parametrize("cfg", CONFIGS, ids=config_id)
def test_slanted_plane_matches_oracle(cfg: dict[str, Any]) -> None:
    left, right, _ = slanted_pair((26, 90), d0=4.3, dx=0.09, dy=0.05, seed=2)
    kw = {"num_disparities": 19, **cfg}
    assert_agree(
        sd.semi_global_match(left, right, **kw),
        ref.semi_global_match(left, right, **kw),
        subpixel=subpixel_of(cfg),
    )


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_dtypes_match_oracle(dtype: Any) -> None:
    left, right = shifted_pair((20, 60), 4, seed=4, dtype=dtype)
    kw = {"num_disparities": 12, "return_confidence": True, "paths": 8}
    assert_agree(
        sd.semi_global_match(left, right, **kw),
        ref.semi_global_match(left, right, **kw),
        subpixel=True,
    )


def test_rgb_matches_oracle_and_is_matched_as_its_grey() -> None:
    left, right = shifted_pair((20, 50), 5, seed=5, rgb=True)
    kw: dict[str, Any] = {"num_disparities": 10, "return_confidence": True}
    native = sd.semi_global_match(left, right, **kw)
    assert_agree(native, ref.semi_global_match(left, right, **kw), subpixel=True)
    gl, gr = grey(left).astype(np.uint8), grey(right).astype(np.uint8)
    grey_result = sd.semi_global_match(gl, gr, **kw)
    np.testing.assert_array_equal(native[0], grey_result[0])
    np.testing.assert_array_equal(native[1], grey_result[1])


@pytest.mark.data
def test_scene_crops_match_oracle(stereo_scenes: list[Any]) -> None:
    for scene in stereo_scenes[:4]:
        left = read_image(scene.left_path)
        right = read_image(scene.right_path)
        h, w = left.shape[:2]
        y0, x0 = h // 3, w // 4
        crop_l = np.ascontiguousarray(left[y0 : y0 + 40, x0 : x0 + 90])
        crop_r = np.ascontiguousarray(right[y0 : y0 + 40, x0 : x0 + 90])
        for paths in (3, 4, 8):
            kw: dict[str, Any] = {"num_disparities": 32, "paths": paths, "return_confidence": True}
            assert_agree(
                sd.semi_global_match(crop_l, crop_r, threads=3, **kw),
                ref.semi_global_match(crop_l, crop_r, **kw),
                subpixel=True,
            )


@pytest.mark.parametrize(
    ("shape", "nd", "md"),
    [
        ((1, 1), 1, 0),
        ((1, 1), 5, -2),
        ((7, 1), 4, 0),
        ((1, 9), 3, 0),
        ((3, 2), 8, -4),
        ((9, 7), 40, 0),
        ((2, 33), 64, -10),
        ((13, 17), 3, 2),
        ((5, 30), 200, -100),
    ],
)
@pytest.mark.parametrize("paths", [3, 4, 8])
def test_odd_shapes_match_oracle(shape: tuple[int, int], nd: int, md: int, paths: int) -> None:
    left, right = shifted_pair(shape, 1, seed=sum(shape) + nd)
    kw: dict[str, Any] = {
        "num_disparities": nd,
        "min_disparity": md,
        "paths": paths,
        "return_confidence": True,
    }
    for isa in SUPPORTED_ISAS:
        native = sd.SemiGlobalMatcher(isa=isa, threads=3, **kw).compute(left, right)
        assert_agree(native, ref.semi_global_match(left, right, **kw), subpixel=True)


@pytest.mark.parametrize(
    ("rows", "starts"),
    [
        (1, [0]),
        (64, [0]),
        (65, [0, 32]),
        (128, [0, 64]),
        (129, [0, 32, 64, 96]),  # ceil(129 / 64) = 3 is odd: 4 stripes
        (150, [0, 37, 75, 112]),
        (288, [0, 48, 96, 144, 192, 240]),
        (720, list(range(0, 720, 60))),  # not 11 stripes of 64 and one of 16
    ],
)
def test_stripe_starts(rows: int, starts: list[int]) -> None:
    assert stripe_starts(rows) == starts


@pytest.mark.parametrize("rows", range(1, 400))
def test_stripes_are_even_and_at_most_64_rows(rows: int) -> None:
    starts = stripe_starts(rows)
    heights = np.diff([*starts, rows])
    assert heights.max() <= 64 and heights.max() - heights.min() <= 1
    assert len(starts) == 1 or len(starts) % 2 == 0
    assert len(starts) <= -(-rows // 64) + 1


@pytest.mark.parametrize("threads", [1, 2, 3])
@pytest.mark.parametrize("rows", [150, 129, 67])
def test_single_pass_stripes_match_oracle(threads: int, rows: int) -> None:
    # paths=3 restarts the path from above at each stripe: 4, 4 and 2 stripes of unequal
    # heights here (stripe_starts).
    left, right, _ = slanted_pair((rows, 50), d0=5.0, dx=0.04, dy=0.03, seed=16)
    kw: dict[str, Any] = {"num_disparities": 16, "paths": 3, "return_confidence": True}
    assert_agree(
        sd.semi_global_match(left, right, threads=threads, **kw),
        ref.semi_global_match(left, right, **kw),
        subpixel=True,
    )


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize(("rows", "nd"), [(150, 20), (257, 20), (257, 16)])
def test_each_stripe_loop_matches_oracle(isa: str, rows: int, nd: int) -> None:
    # paths=3 has two stripe loops: the plain one (the baseline kernels, or ndisp not a
    # multiple of 16) and the fused row's (AVX2 and up, ndisp 16). Both hand out 4 (150 rows)
    # or 6 (257 rows: ceil(257 / 64) = 5 is odd) stripes one at a time, several per thread.
    left, right, _ = slanted_pair((rows, 40), d0=6.0, dx=0.05, dy=0.02, seed=rows + nd)
    kw: dict[str, Any] = {
        "num_disparities": nd,
        "min_disparity": -2,
        "paths": 3,
        "return_confidence": True,
    }
    expected = ref.semi_global_match(left, right, **kw)
    for threads in (1, 2, 3):
        native = sd.SemiGlobalMatcher(isa=isa, threads=threads, **kw).compute(left, right)
        assert_agree(native, expected, subpixel=True)


@pytest.mark.parametrize("paths", [3, 4, 8])
def test_largest_p2_and_many_disparities_do_not_overflow(paths: int) -> None:
    # Path costs reach 144 + p2 < 2**14 and sums paths * (144 + p2) <= 65535 on a pair that
    # matches nowhere.
    rng = np.random.default_rng(9)
    left = rng.integers(0, 256, (12, 40)).astype(np.uint8)
    right = rng.integers(0, 256, (12, 40)).astype(np.uint8)
    p2 = min(65535 // paths, 16383) - 144
    kw: dict[str, Any] = {
        "num_disparities": 300,
        "min_disparity": -150,
        "p1": p2,
        "p2": p2,
        "p2_step": 0,
        "paths": paths,
        "uniqueness_ratio": 0,
        "return_confidence": True,
    }
    assert_agree(
        sd.semi_global_match(left, right, **kw),
        ref.semi_global_match(left, right, **kw),
        subpixel=True,
    )


def test_largest_num_disparities_on_a_tiny_image() -> None:
    left, right = shifted_pair((4, 6), 2, seed=10)
    kw: dict[str, Any] = {"num_disparities": 4096, "min_disparity": -2048, "paths": 8}
    assert_agree(
        sd.semi_global_match(left, right, **kw),
        ref.semi_global_match(left, right, **kw),
        subpixel=True,
    )


# ------------------------------------------------------------------------------------------
# What it finds


@pytest.mark.parametrize("paths", [3, 4, 8])
def test_step_in_random_dots_is_recovered_exactly(paths: int) -> None:
    left, right, truth = step_pair((60, 120), 14, 5, seed=11)
    d = sd.semi_global_match(left, right, num_disparities=24, paths=paths, subpixel=False)
    known = np.isfinite(truth)
    # Away from the square's edges and the occlusions (the box's and the median's reach, and
    # two more columns), every pixel is exact.
    inner = known.copy()
    for dy in range(-2, 3):
        for dx in range(-4, 5):
            moved = np.roll(np.roll(truth, dy, axis=0), dx, axis=1)
            inner &= np.isfinite(moved) & (moved == truth)
    inner[:2] = inner[-2:] = False
    inner[:, :2] = inner[:, -2:] = False
    np.testing.assert_array_equal(d[inner], truth[inner])
    assert inner.sum() > 0.7 * known.sum()


def test_slanted_plane_is_recovered_to_subpixel_accuracy() -> None:
    left, right, disp = slanted_pair((40, 120), d0=6.2, dx=0.05, dy=0.02, seed=3)
    est = sd.semi_global_match(left, right, num_disparities=24)
    good = np.isfinite(est)
    assert good.mean() > 0.8
    err = np.abs(est - disp)[good]
    assert np.median(err) < 0.25
    assert (err < 1).mean() > 0.95


def test_border_band_is_matched_over_the_disparities_inside_the_image() -> None:
    left, right = shifted_pair((30, 80), 5, seed=12)
    kw: dict[str, Any] = {"num_disparities": 32, "subpixel": False}
    clip = sd.semi_global_match(left, right, **kw)
    opencv = sd.semi_global_match(left, right, border="opencv", **kw)
    # OpenCV's rule: the left num_disparities - 1 columns are NaN.
    assert np.isnan(opencv[:, :31]).all()
    assert np.isfinite(opencv[3:-3, 31:-3]).all()
    # Clipped: the band is matched where the true disparity lies inside the image; columns
    # left of the shift (whose match is outside the right image) cannot be right.
    np.testing.assert_array_equal(clip[3:-3, 8:31], 5.0)
    np.testing.assert_array_equal(clip[:, 31:], opencv[:, 31:])
    assert np.isnan(clip[:, 0]).all() or (clip[:, 0][np.isfinite(clip[:, 0])] == 0).all()


def test_fill_takes_the_background_along_the_row() -> None:
    from stereodepth.semi_global import fill_background

    nan = np.float32(np.nan)
    d = np.array(
        [
            [nan, 3.0, nan, nan, 7.0, nan],
            [nan, nan, nan, nan, nan, nan],
            [5.0, nan, 2.5, 2.5, nan, nan],
        ],
        dtype=np.float32,
    )
    out = fill_background(d.copy())
    expected = np.array(
        [[3.0, 3.0, 3.0, 3.0, 7.0, 7.0], [nan] * 6, [5.0, 2.5, 2.5, 2.5, 2.5, 2.5]],
        dtype=np.float32,
    )
    np.testing.assert_array_equal(out, expected)
    left, right = shifted_pair((30, 60), 4, seed=17)
    filled, conf = sd.semi_global_match(
        left, right, num_disparities=16, fill=True, return_confidence=True
    )
    plain, conf0 = sd.semi_global_match(left, right, num_disparities=16, return_confidence=True)
    assert np.isfinite(filled).all()
    np.testing.assert_array_equal(filled[np.isfinite(plain)], plain[np.isfinite(plain)])
    np.testing.assert_array_equal(conf, conf0)  # filled pixels keep confidence 0


def test_candidates_outside_the_image_never_win() -> None:
    left, right = shifted_pair((20, 50), 3, seed=13)
    d = sd.semi_global_match(
        left,
        right,
        num_disparities=40,
        subpixel=False,
        lr_max_diff=None,
        uniqueness_ratio=0,
        median=False,
        speckle_window=0,
    )
    x = np.arange(50)
    # Columns 0 and 1 have one and two candidates inside the image, none more than one
    # disparity from the other: no rival to tell the winner from, NaN (border="clip").
    assert np.isnan(d[:, :2]).all()
    # Column 2 (candidates 0, 1, 2) loses a winner of 1 the same way.
    assert ((d[:, 2] == 0) | (d[:, 2] == 2) | np.isnan(d[:, 2])).all()
    assert (d[:, 3:] <= x[None, 3:]).all()


# ------------------------------------------------------------------------------------------
# Instruction sets and threads


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("paths", [3, 4, 8])
def test_each_isa_matches_the_scalar_path(isa: str, paths: int) -> None:
    # Every vector width of the costs' rows (16, 32 and 64 bytes, and 32 + 16), both boxes.
    left, right, _ = slanted_pair((64, 150), d0=9.0, dx=0.1, dy=-0.03, seed=14)
    for nd, bs in itertools.product((7, 16, 32, 33, 48, 64, 80, 96, 100, 160), (1, 3)):
        kw: dict[str, Any] = {
            "num_disparities": nd,
            "paths": paths,
            "block_size": bs,
            "return_confidence": True,
        }
        a = sd.SemiGlobalMatcher(isa="baseline", **kw).compute(left, right)
        b = sd.SemiGlobalMatcher(isa=isa, **kw).compute(left, right)
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("width", [1, 2, 3, 8, 9, 10, 11, 17, 18, 19, 33, 41, 150])
def test_median_stage_is_the_oracles_median(isa: str, width: int) -> None:
    # The median kernel alone: the matcher with it equals the oracle's median3 of the same
    # matcher's output without it, bit for bit. The widths put every column of a row on each
    # of the kernel's ways (whole vectors, the overlapping tail vector, the scalar edges), and
    # the noisy pair leaves NaN in some windows and none in others, so that both the network
    # for nine valid values and the ranks for fewer are taken.
    left, right, _ = slanted_pair((23, 160), d0=9.0, dx=0.1, dy=-0.03, seed=width)
    rng = np.random.default_rng(width)
    noise = rng.integers(0, 256, size=left.shape).astype(np.uint8)
    right = np.where(rng.random(left.shape) < 0.15, noise, right).astype(np.uint8)
    left, right = np.ascontiguousarray(left[:, -width:]), np.ascontiguousarray(right[:, -width:])
    kw: dict[str, Any] = {"num_disparities": 16, "speckle_window": 0, "isa": isa, "threads": 2}
    raw = sd.SemiGlobalMatcher(median=False, **kw).compute(left, right)
    filtered = sd.SemiGlobalMatcher(median=True, **kw).compute(left, right)
    assert isinstance(raw, np.ndarray) and isinstance(filtered, np.ndarray)
    if width >= 18:
        # Both kinds of window occur (else the test would not reach both ways).
        p = np.pad(np.isnan(raw), 1)
        h = raw.shape[0]
        nans = sum(p[dy : dy + h, dx : dx + width] for dy in range(3) for dx in range(3))
        assert (nans[1:-1, 1:-1] == 0).any() and (nans[1:-1, 1:-1] > 0).any()
    np.testing.assert_array_equal(filtered, median3(raw))


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("nd", [*range(16, 304, 16), 352])
def test_every_vector_count_of_the_fused_row_matches_the_scalar_path(isa: str, nd: int) -> None:
    # paths=3 with ndisp a multiple of 16 takes the fused row, compiled once per vector count
    # (1 to 12 and 16 with AVX2) and once for any other count; uniqueness and confidence take
    # its other instance. The costs' box takes whole vectors, whole and half ones (up to 288
    # with AVX-512), or any width (352).
    left, right, _ = slanted_pair((37, 300), d0=0.4 * nd, dx=0.05, dy=0.02, seed=nd)
    for kw in (
        {"num_disparities": nd, "uniqueness_ratio": 0},
        {"num_disparities": nd, "min_disparity": -5, "uniqueness_ratio": 10,
         "return_confidence": True},
    ):  # fmt: skip
        a = sd.SemiGlobalMatcher(isa="baseline", paths=3, **kw).compute(left, right)
        b = sd.SemiGlobalMatcher(isa=isa, paths=3, **kw).compute(left, right)
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("nd", [*range(16, 304, 16), 352])
def test_every_vector_count_of_the_plain_fused_row_matches_the_scalar_path(
    isa: str, paths: int, nd: int
) -> None:
    # paths 4 and 8 end in the plain layout's fused row, whose pass 2 keeps its path and
    # window in registers up to a few vectors per pixel (a count known when compiled) and in
    # memory beyond: every vector count of 16, 32 and 64 lanes, with and without the
    # second best.
    left, right, _ = slanted_pair((29, 310), d0=0.4 * nd, dx=0.05, dy=0.02, seed=nd + paths)
    for kw in (
        {"num_disparities": nd, "uniqueness_ratio": 0},
        {"num_disparities": nd, "min_disparity": -3, "uniqueness_ratio": 10,
         "return_confidence": True},
    ):  # fmt: skip
        a = sd.SemiGlobalMatcher(isa="baseline", paths=paths, **kw).compute(left, right)
        b = sd.SemiGlobalMatcher(isa=isa, paths=paths, **kw).compute(left, right)
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize(("nd", "md"), [(5, -7), (3, -30), (21, -40), (17, -5), (33, 8)])
@pytest.mark.parametrize("lr_max_diff", [1.0, None])
@pytest.mark.parametrize("paths", [3, 4, 8])
def test_disparities_not_a_multiple_of_16_match_oracle(
    isa: str, nd: int, md: int, lr_max_diff: float | None, paths: int
) -> None:
    # The paths run over ndisp rounded up to 16; the extra candidates never win. With
    # every disparity negative, the pixels at the right edge have no candidate inside the
    # image while their extra candidates' right columns are inside: they must stay out of the
    # right image's winners (they once made the left-right check fail there).
    left, right = shifted_pair((23, 90), 3, seed=nd)
    kw: dict[str, Any] = {
        "num_disparities": nd,
        "min_disparity": md,
        "lr_max_diff": lr_max_diff,
        "paths": paths,
        "return_confidence": True,
    }
    native = sd.SemiGlobalMatcher(isa=isa, **kw).compute(left, right)
    assert_agree(native, ref.semi_global_match(left, right, **kw), subpixel=True)


def test_run_disparities() -> None:
    assert [run_disparities(n) for n in (1, 15, 16, 17, 60, 4096)] == [16, 16, 16, 32, 64, 4096]


@pytest.mark.parametrize(
    ("fn", "value", "error"),
    [
        (run_disparities, 0, ValueError),
        (run_disparities, 16.0, TypeError),
        (stripe_starts, 0, ValueError),
        (stripe_starts, "64", TypeError),
    ],
)
def test_rules_reject_bad_counts(fn: Any, value: Any, error: type[Exception]) -> None:
    with pytest.raises(error, match="must be an integer"):
        fn(value)


def test_unknown_isa_is_rejected() -> None:
    with pytest.raises(ValueError, match="isa must be one of"):
        sd.SemiGlobalMatcher(num_disparities=8, isa="sse9")
    with pytest.raises(TypeError, match="isa must be a str, got int 3"):
        sd.SemiGlobalMatcher(num_disparities=8, isa=3)  # type: ignore[arg-type]


@pytest.mark.parametrize("paths", [3, 4, 8])
def test_thread_counts_give_identical_output(paths: int) -> None:
    left, right, _ = slanted_pair((70, 161), d0=10.0, dx=0.07, dy=0.04, seed=15)
    kw: dict[str, Any] = {"num_disparities": 32, "paths": paths, "return_confidence": True}
    one = sd.semi_global_match(left, right, threads=1, **kw)
    for threads in (2, 3, 7):
        many = sd.semi_global_match(left, right, threads=threads, **kw)
        np.testing.assert_array_equal(one[0], many[0])
        np.testing.assert_array_equal(one[1], many[1])


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("rows", [1, 2, 3, 4, 5, 33])
def test_passes_at_once_match_one_thread_and_the_oracle(isa: str, paths: int, rows: int) -> None:
    # With two threads, paths 4 and 8 run the downward and upward passes at once: the downward
    # one computes the costs and stores the sums of the rows above the middle (rows // 2), the
    # upward one those of the rest, and each adds to the other's rows once they are done, then
    # finishes them (horizontal paths, decision). Every height, including those that leave
    # one side empty, gives one thread's output.
    left, right, _ = slanted_pair((rows, 75), d0=6.0, dx=0.05, dy=0.1, seed=40 + rows)
    kw: dict[str, Any] = {"num_disparities": 16, "paths": paths, "return_confidence": True}
    one = sd.SemiGlobalMatcher(isa=isa, threads=1, **kw).compute(left, right)
    two = sd.SemiGlobalMatcher(isa=isa, threads=2, **kw).compute(left, right)
    np.testing.assert_array_equal(one[0], two[0])
    np.testing.assert_array_equal(one[1], two[1])
    assert_agree(two, ref.semi_global_match(left, right, **kw), subpixel=True)


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("paths", [4, 8])
def test_column_bands_match_the_passes_at_once(isa: str, paths: int) -> None:
    # Three or more threads split the columns of the vertical passes into bands (for paths=8
    # they meet at every row), but paths 4 and 8 never run more threads than CPUs: on a
    # machine with two, only the test hook makes two threads take the bands.
    from stereodepth import _core

    left, right, _ = slanted_pair((45, 97), d0=8.0, dx=0.06, dy=0.05, seed=60 + paths)
    kw: dict[str, Any] = {"num_disparities": 24, "paths": paths, "return_confidence": True}
    want = sd.SemiGlobalMatcher(isa=isa, threads=2, **kw).compute(left, right)
    _core._sgm_column_bands_for_tests(True)
    try:
        bands = sd.SemiGlobalMatcher(isa=isa, threads=2, **kw).compute(left, right)
    finally:
        _core._sgm_column_bands_for_tests(False)
    np.testing.assert_array_equal(bands[0], want[0])
    np.testing.assert_array_equal(bands[1], want[1])
    assert_agree(bands, ref.semi_global_match(left, right, **kw), subpixel=True)


def test_concurrent_calls_from_python_threads() -> None:
    pairs = [shifted_pair((40, 90), s, seed=20 + s) for s in range(1, 7)]
    kw: dict[str, Any] = {"num_disparities": 16, "threads": 2}
    expected = [sd.semi_global_match(left, right, **kw) for left, right in pairs]
    shared = sd.SemiGlobalMatcher(**kw)
    barrier = threading.Barrier(6)

    def run(i: int) -> tuple[np.ndarray, np.ndarray]:
        barrier.wait()
        left, right = pairs[i]
        own = sd.semi_global_match(left, right, **kw)
        common = shared.compute(left, right)
        assert isinstance(own, np.ndarray) and isinstance(common, np.ndarray)
        return own, common

    with ThreadPoolExecutor(6) as pool:
        results = list(pool.map(run, range(6)))
    for (own, common), exp in zip(results, expected, strict=True):
        np.testing.assert_array_equal(own, exp)
        np.testing.assert_array_equal(common, exp)


def test_matcher_reuses_its_buffers_across_sizes_and_reports_params() -> None:
    m = sd.SemiGlobalMatcher(num_disparities=12, paths=8)
    for shape in [(30, 60), (10, 20), (31, 61)]:
        left, right = shifted_pair(shape, 3, seed=shape[0])
        np.testing.assert_array_equal(
            m.compute(left, right), sd.semi_global_match(left, right, num_disparities=12, paths=8)
        )
    assert m.params["paths"] == 8 and m.params["subpixel"] == "equiangular"
    assert repr(m).startswith("SemiGlobalMatcher(num_disparities=12, ")
    assert m.isa in SUPPORTED_ISAS
    assert "isa=" not in repr(m)
    # The repr makes the same matcher, the instruction set it was made for included.
    pinned = sd.SemiGlobalMatcher(num_disparities=12, paths=8, isa="baseline")
    assert repr(pinned).endswith(", isa='baseline')")
    again = eval(repr(pinned), {"SemiGlobalMatcher": sd.SemiGlobalMatcher})
    assert again.params == pinned.params and again.isa == "baseline"


def test_confidence_is_in_unit_interval_and_zero_on_holes() -> None:
    left, right = shifted_pair((30, 70), 4, seed=30)
    d, c = sd.semi_global_match(left, right, num_disparities=16, return_confidence=True)
    assert c.dtype == np.float32 and ((c >= 0) & (c <= 1)).all()
    assert (c[np.isnan(d)] == 0).all()


# ------------------------------------------------------------------------------------------
# Memory


@pytest.mark.parametrize(
    ("shape", "kw", "error", "fragment"),
    [
        ((0, 10), {}, ValueError, "shape[0] must be an integer >= 1, got 0"),
        ((10, -2), {}, ValueError, "shape[1] must be an integer >= 1, got -2"),
        ((2.5, 3), {}, TypeError, "shape[0] must be an integer, got float 2.5"),
        ((3,), {}, ValueError, "shape must be (H, W), two integers, got (3,)"),
        ("ab", {}, TypeError, "shape must be a tuple (H, W), got str 'ab'"),
        ((10, 20), {"num_disparities": 0}, ValueError, "num_disparities"),
        ((10, 20), {"paths": 5}, ValueError, "paths must be 3, 4 or 8, got 5"),
        ((10, 20), {"threads": -1}, ValueError, "threads must be an integer >= 0, got -1"),
        ((10, 20), {"isa": 3}, TypeError, "isa must be a str, got int 3"),
    ],
)
def test_memory_estimate_rejects_bad_input(
    shape: Any, kw: dict[str, Any], error: type[Exception], fragment: str
) -> None:
    # It passed shapes and parameters straight to the native call: (0, 10) and (-1, 5) gave
    # a figure, (2.5, 3) pybind11's signature dump, (3,) an IndexError.
    from stereodepth.semi_global import memory_estimate

    with pytest.raises(error) as info:
        memory_estimate(shape, **{"num_disparities": 64, **kw})
    assert fragment in str(info.value)


def test_memory_estimate_threads_none_is_every_core() -> None:
    from stereodepth.semi_global import memory_estimate

    cores = sd.build_info()["default_threads"]
    est = memory_estimate((480, 640), num_disparities=64, threads=None)
    assert est == memory_estimate((480, 640), num_disparities=64, threads=cores)


def test_memory_estimate_and_refusal() -> None:
    from stereodepth.semi_global import memory_estimate

    est = memory_estimate((1080, 1920), num_disparities=256, paths=4)
    assert 3 * 1080 * 1920 * 256 <= est < 3.2 * 1080 * 1920 * 256
    # One pass: a few rows of W x D per thread (at most 16 bytes per column and disparity,
    # the baseline build's 16-bit costs), nothing per pixel.
    for isa in SUPPORTED_ISAS:
        one = memory_estimate((1080, 1920), num_disparities=256, paths=3, threads=2, isa=isa)
        assert 2 * 1920 * 256 * 4 < one < 2 * 1920 * 256 * 16
        assert one == memory_estimate((4000, 1920), num_disparities=256, threads=2, isa=isa)
        assert one > memory_estimate((1080, 1920), num_disparities=256, threads=1, isa=isa)
        small = memory_estimate((1080, 1920), num_disparities=256, threads=2, isa=isa, block_size=1)
        assert small < one
    left, right = shifted_pair((100, 200), 3, seed=31)
    with pytest.raises(
        ValueError,
        match=r"semi-global matching of a 200x100 px pair with num_disparities=512 and paths=4 "
        r"needs about \d+ MiB, above max_memory_mb=5; lower num_disparities, use paths=3 ",
    ):
        sd.semi_global_match(left, right, num_disparities=512, paths=4, max_memory_mb=5)
    # A tiny limit names a tiny need (not "about 0 MiB"); paths=3 is not offered to paths=3.
    with pytest.raises(
        ValueError, match=r"needs about \d+\.\d\d MiB, above max_memory_mb=0\.001;"
    ) as e:
        sd.semi_global_match(left, right, num_disparities=16, paths=3, max_memory_mb=0.001)
    assert "0.00 MiB" not in str(e.value) and "use paths=3" not in str(e.value)


@pytest.mark.parametrize("kind", ["view", "uint16", "big-endian", "bgr"])
def test_a_pair_above_max_memory_mb_is_refused_before_it_is_copied(kind: str) -> None:
    # The estimate was checked in the kernel, after the pair had been copied (a strided view),
    # stretched (uint16) or converted: a pair too large for memory got a MemoryError there,
    # or took seconds and gigabytes to be refused (a big-endian pair: converted to the
    # machine's byte order before the size was checked). A broadcast view costs no memory,
    # but every copy of it does.
    import tracemalloc

    shape = (20000, 30000) if kind != "bgr" else (20000, 30000, 3)
    dtype = {"uint16": np.dtype(np.uint16), "big-endian": np.dtype(">u2")}.get(kind, np.uint8)
    left = np.broadcast_to(np.array(7, dtype=dtype), shape)
    right = np.broadcast_to(np.array(9, dtype=dtype), shape)
    kwargs = {"channel_order": "bgr"} if kind == "bgr" else {}
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=r"30000x20000 px pair .* above max_memory_mb=64;"):
            sd.semi_global_match(
                left, right, num_disparities=64, paths=8, max_memory_mb=64, threads=1, **kwargs
            )
        matcher = sd.SemiGlobalMatcher(
            num_disparities=64, paths=8, max_memory_mb=64, threads=1, **kwargs
        )
        with pytest.raises(ValueError, match=r"above max_memory_mb=64;"):
            matcher.compute(left, right)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50_000_000, peak


_PEAK_CHILD = """
import json, sys
import numpy as np
import stereodepth as sd
from stereodepth.semi_global import memory_estimate

h, w, nd, threads, rgb = (int(a) for a in sys.argv[1:])
rng = np.random.default_rng(3)
wide = rng.integers(0, 256, size=(h, w + 20, 3) if rgb else (h, w + 20), dtype=np.uint8)
left, right = np.ascontiguousarray(wide[:, :w]), np.ascontiguousarray(wide[:, 20:])
del wide
kw = dict(num_disparities=nd, threads=threads, speckle_window=0, return_confidence=True)
sd.semi_global_match(left[:8, :64], right[:8, :64], **{**kw, "num_disparities": 16})

def kib(field):
    with open("/proc/self/status") as f:
        return next(int(s.split()[1]) for s in f if s.startswith(field + ":"))

with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # the peak resident set := the resident set
before = kib("VmRSS")
disp, conf = sd.semi_global_match(left, right, **kw)
growth = (kib("VmHWM") - before) * 1024 - disp.nbytes - conf.nbytes
est = memory_estimate((h, w), num_disparities=nd, threads=threads)
print(json.dumps({"growth": growth, "estimate": est, "valid": float(np.isfinite(disp).mean())}))
"""


def _peak_growth(h: int, w: int, nd: int, threads: int, rgb: bool) -> dict[str, Any]:
    """In a fresh process: how much the peak resident set grows over one call, less the
    outputs (so: the matcher's own buffers)."""
    env = dict(os.environ)
    pkg_root = str(Path(sd.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([pkg_root, env.get("PYTHONPATH", "")])
    args = [str(v) for v in (h, w, nd, threads, int(rgb))]
    out = subprocess.run(
        [sys.executable, "-c", _PEAK_CHILD, *args],
        check=True,
        capture_output=True,
        text=True,
        env=env,
    )
    result: dict[str, Any] = json.loads(out.stdout)
    return result


def _can_reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return False
    return True


@pytest.mark.skipif(not _can_reset_peak(), reason="needs Linux /proc/self/clear_refs")
@pytest.mark.skipif(
    bool(sd.build_info()["sanitizers"]),
    reason="a sanitizer's allocator (red zones, quarantine) is not the memory users get",
)
@pytest.mark.parametrize("rgb", [False, True], ids=["grey", "rgb"])
def test_single_pass_peak_memory_does_not_grow_with_the_height(rgb: bool) -> None:
    # Issue 11: paths=3 keeps a few rows per thread and nothing image-sized beside the
    # inputs and the outputs. Four times the rows, the same width: one byte per added pixel
    # would be 768 KiB more; the old image-sized buffers (census, grey, the disparity before
    # the median) were 9 to 11 bytes per pixel.
    w, nd, threads = 1024, 64, 2
    low, high = (_peak_growth(h, w, nd, threads, rgb) for h in (256, 1024))
    assert low["valid"] > 0.9 and high["valid"] > 0.9  # the pair was matched
    added = (1024 - 256) * w
    assert high["growth"] - low["growth"] < added // 2
    # The estimate behind max_memory_mb covers what was used, and is not far above it.
    for m in (low, high):
        assert m["growth"] <= m["estimate"] + 128 * 1024
        assert m["estimate"] < m["growth"] + 512 * 1024


# ------------------------------------------------------------------------------------------
# Rejected input: one test per rule

GOOD = shifted_pair((8, 20), 2, seed=40)


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"num_disparities": 0}, ValueError, r"num_disparities must be an integer in \[1, 4096\]"),
        ({"num_disparities": 1.5}, TypeError, "num_disparities must be an integer, got float"),
        (
            {"num_disparities": 8, "min_disparity": 40000},
            ValueError,
            r"min_disparity must be an integer in \[-32768, 32768\], got 40000",
        ),
        ({"num_disparities": 8, "block_size": 5}, ValueError, "block_size must be 1 or 3 .*got 5"),
        ({"num_disparities": 8, "block_size": 3.0}, TypeError, "block_size must be an integer"),
        ({"num_disparities": 8, "paths": 5}, ValueError, "paths must be 3, 4 or 8, got 5"),
        ({"num_disparities": 8, "paths": "8"}, TypeError, "paths must be an integer, got str"),
        ({"num_disparities": 8, "p1": -1}, ValueError, "p1 must be an integer >= 0, got -1"),
        ({"num_disparities": 8, "p1": 2.0}, TypeError, "p1 must be an integer, got float"),
        (
            {"num_disparities": 8, "p1": 50, "p2": 40},
            ValueError,
            r"p2 must be an integer in \[p1, 16239\] = \[50, 16239\] for paths=3 and "
            r"block_size=3 .*got 40",
        ),
        (
            {"num_disparities": 8, "paths": 8, "p2": 8100},
            ValueError,
            r"p2 must be an integer in \[p1, 8047\].*got 8100",
        ),
        ({"num_disparities": 8, "p2_step": -1}, ValueError, "p2_step must be an integer >= 0"),
        ({"num_disparities": 8, "p2_step": 70000}, ValueError, "p2_step must be an integer <="),
        (
            {"num_disparities": 8, "subpixel": "cubic"},
            ValueError,
            "subpixel must be True, False, 'parabola' or 'equiangular', got 'cubic'",
        ),
        ({"num_disparities": 8, "subpixel": 1}, TypeError, "subpixel must be True, False"),
        (
            {"num_disparities": 8, "uniqueness_ratio": -1},
            ValueError,
            "uniqueness_ratio must be a finite number >= 0, got -1",
        ),
        (
            {"num_disparities": 8, "lr_max_diff": float("nan")},
            ValueError,
            "lr_max_diff must be a finite number >= 0, got nan",
        ),
        ({"num_disparities": 8, "median": 1}, TypeError, "median must be a bool, got int 1"),
        ({"num_disparities": 8, "fill": "yes"}, TypeError, "fill must be a bool, got str 'yes'"),
        (
            {"num_disparities": 8, "speckle_window": -1},
            ValueError,
            "speckle_window must be an integer >= 0, got -1",
        ),
        (  # above a C int: refused by name, not by the binding's argument conversion
            {"num_disparities": 8, "speckle_window": 2**40},
            ValueError,
            r"speckle_window must be an integer <= 2147483647, got 1099511627776",
        ),
        (
            {"num_disparities": 8, "p1": 20000, "p2": 20000},
            ValueError,
            r"p1 must be an integer in \[0, 16239\] for paths=3 and block_size=3",
        ),
        (
            {"num_disparities": 8, "speckle_range": float("inf")},
            ValueError,
            "speckle_range must be a finite number >= 0, got inf",
        ),
        (
            {"num_disparities": 8, "border": "wrap"},
            ValueError,
            "border must be 'clip' or 'opencv', got 'wrap'",
        ),
        ({"num_disparities": 8, "border": None}, TypeError, "border must be 'clip' or 'opencv'"),
        (
            {"num_disparities": 8, "max_memory_mb": 0},
            ValueError,
            "max_memory_mb must be a finite number > 0, got 0",
        ),
        ({"num_disparities": 8, "threads": -1}, ValueError, "threads must be an integer >= 0"),
        (
            {"num_disparities": 8, "return_confidence": "yes"},
            TypeError,
            "return_confidence must be a bool, got str 'yes'",
        ),
    ],
)
def test_rejected_parameters(kwargs: dict[str, Any], exc: type[Exception], match: str) -> None:
    left, right = GOOD
    with pytest.raises(exc, match=match):
        sd.semi_global_match(left, right, **kwargs)
    with pytest.raises(exc, match=match):
        ref.semi_global_match(left, right, **kwargs)


@pytest.mark.parametrize(
    ("left", "right", "exc", "match"),
    [
        ([[1, 2]], GOOD[1], TypeError, "left must be a numpy.ndarray"),
        (GOOD[0].astype(np.float32), GOOD[1], TypeError, "left must be .* got dtype float32"),
        (GOOD[0], GOOD[1][:, :-1], ValueError, "left and right must have the same shape"),
        (GOOD[0], GOOD[1].astype(np.uint16), TypeError, "left and right must have the same dtype"),
        (np.zeros((0, 4), np.uint8), np.zeros((0, 4), np.uint8), ValueError, "at least one row"),
        (np.zeros((4, 4, 4), np.uint8), np.zeros((4, 4, 4), np.uint8), ValueError, "got shape"),
    ],
)
def test_rejected_images(left: Any, right: Any, exc: type[Exception], match: str) -> None:
    with pytest.raises(exc, match=match):
        sd.semi_global_match(left, right, num_disparities=8)


# ------------------------------------------------------------------------------------------
# stereodepth eval


@pytest.mark.data
def test_eval_runs_sgm_and_opencvs_sgbm_modes(
    stereo_data_dir: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    from stereodepth import cli
    from stereodepth.metrics import evaluate

    pytest.importorskip("PIL.Image")
    pytest.importorskip("cv2")
    scene = "mb2001-tsukuba"
    argv = ["eval", str(stereo_data_dir), "--scene", scene, "--repeat", "1", "--json"]
    methods = ["sgm", "opencv-sgbm", "opencv-sgbm-3way", "opencv-sgbm-hh"]
    assert cli.main([*argv, "--method", *methods, "--threads", "2"]) == 0
    report = json.loads(capsys.readouterr().out)
    by_method = {r["method"]: r for r in report["results"]}
    assert set(by_method) == set(methods)
    folder = stereo_data_dir / scene
    left, right = read_image(folder / "left.png"), read_image(folder / "right.png")
    gt = np.load(folder / "disp_gt.npy")
    mask = np.load(folder / "mask_nonocc.npy")
    nd = by_method["sgm"]["num_disparities"]
    expected = evaluate(sd.semi_global_match(left, right, num_disparities=nd), gt, mask)
    assert by_method["sgm"]["metrics"]["bad_2"] == pytest.approx(expected.bad_2)
    assert all(r["metrics"]["density"] > 0.9 for r in by_method.values())
    assert cli.main([*argv, "--method", "sgm:5"]) == 2
    assert "block size of sgm must be 1 or 3, got 5" in capsys.readouterr().err


def test_channel_order_and_intensity_range_as_the_block_matcher() -> None:
    """BGR frames give the disparity of the same frames in RGB; a uint16 pair is stretched from
    its joint range (or intensity_range) like the block matcher's, in the kernel and the oracle."""
    rng = np.random.default_rng(7)
    rgb = rng.integers(0, 256, (40, 64, 3), dtype=np.uint8)
    right = np.roll(rgb, -5, axis=1)
    want = sd.semi_global_match(rgb, right, num_disparities=16)
    got = sd.semi_global_match(
        rgb[..., ::-1], right[..., ::-1], num_disparities=16, channel_order="bgr"
    )
    np.testing.assert_array_equal(got, want)
    oracle = sd.reference.semi_global_match(
        rgb[..., ::-1], right[..., ::-1], num_disparities=16, channel_order="bgr"
    )
    np.testing.assert_allclose(oracle, want, atol=1e-3, equal_nan=True)
    # Without the order, the BGR frames are another grey image: another disparity.
    assert not np.array_equal(
        sd.semi_global_match(rgb[..., ::-1], right[..., ::-1], num_disparities=16),
        want,
        equal_nan=True,
    )
    grey = rgb[..., 1]
    g16 = (7000 + 6 * grey.astype(np.uint16)).astype(np.uint16)
    r16 = np.roll(g16, -5, axis=1)
    native = sd.semi_global_match(g16, r16, num_disparities=16, intensity_range=(7000, 8530))
    np.testing.assert_array_equal(
        native, sd.semi_global_match(grey, np.roll(grey, -5, axis=1), num_disparities=16)
    )
    with pytest.raises(ValueError, match="channel_order must be 'rgb' or 'bgr', got 'rbg'"):
        sd.SemiGlobalMatcher(num_disparities=16, channel_order="rbg")


@pytest.mark.parametrize("ratio", [1e300, 1e308, float(np.finfo(np.float64).max)])
def test_huge_uniqueness_ratio_matches_the_oracle(ratio: float) -> None:
    # best * (100 + ratio) overflows to inf from 1e308 on: the oracle printed numpy's
    # "overflow encountered in multiply" (an error under -W error). No second-best sum passes
    # a winner above 0; a winning sum of 0 still passes.
    rng = np.random.default_rng(12)
    left = rng.integers(0, 256, (24, 40), dtype=np.uint8)
    right = np.roll(left, -3, axis=1)
    right[:8, ::7] = 0
    kw: dict[str, Any] = {"num_disparities": 8, "uniqueness_ratio": ratio, "paths": 4}
    got = sd.semi_global_match(left, right, **kw)
    want = ref.semi_global_match(left, right, **kw)
    np.testing.assert_array_equal(got, want, strict=True)
    assert np.isfinite(got).any() and np.isnan(got).any()


@pytest.mark.parametrize(
    ("disparity", "exc", "match"),
    [
        # were "too many values to unpack (expected 2)", "not enough values to unpack",
        # "'list' object has no attribute 'shape'" and "assignment destination is read-only"
        (
            np.zeros((2, 3, 4), np.float32),
            ValueError,
            r"^disparity must be 2-D \(H, W\).*got shape \(2, 3, 4\)$",
        ),
        (np.zeros(4, np.float32), ValueError, r"^disparity must be 2-D .*got shape \(4,\)$"),
        ([[1.0, float("nan")]], TypeError, "^disparity must be a numpy.ndarray .*got list$"),
        (
            np.zeros((2, 2), np.int16),
            TypeError,
            "^disparity must be a float array .*got dtype int16$",
        ),
        ("read-only", ValueError, r"^disparity must be writeable \(it is filled in place\)$"),
    ],
)
def test_fill_background_names_what_it_cannot_fill(disparity: Any, exc: type, match: str) -> None:
    from stereodepth.semi_global import fill_background

    if isinstance(disparity, str):
        disparity = np.array([[1.0, np.nan]], np.float32)
        disparity.flags.writeable = False
    with pytest.raises(exc, match=match):
        fill_background(disparity)
