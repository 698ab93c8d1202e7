"""stereodepth.dask checks what it can when the lazy array is built, with the numpy API's
messages: every check that depends only on the parameters and the frames' shape and dtype
(the semi-global matcher's memory, empty frames, the block matcher's width times
num_disparities), the user's shape in the messages (not an internal probe's), and no frame's
work while building the graph."""

from __future__ import annotations

import re
import tracemalloc
from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth.semi_global import memory_estimate

da = pytest.importorskip("dask.array")
sdd = pytest.importorskip("stereodepth.dask")

RIG = {"focal_px": 718.856, "baseline_m": 0.537166}


def numpy_error(call: Any) -> tuple[type, str]:
    """The exception type and message the numpy API raises."""
    with pytest.raises((TypeError, ValueError)) as info:
        call()
    return info.type, str(info.value)


def assert_same_error(lazy_call: Any, numpy_call: Any) -> None:
    """``lazy_call`` (building a dask array) raises what ``numpy_call`` raises, word for word."""
    exc, message = numpy_error(numpy_call)
    with pytest.raises(exc, match=f"^{re.escape(message)}$"):
        lazy_call()


@pytest.mark.parametrize(
    ("frame", "params"),
    [
        ((400, 600), {"num_disparities": 128, "paths": 8, "max_memory_mb": 1}),
        ((400, 600), {"num_disparities": 128, "paths": 3, "max_memory_mb": 0.5}),
        ((400, 600), {"num_disparities": 128, "paths": 3, "threads": 4, "max_memory_mb": 2}),
        ((400, 600, 3), {"num_disparities": 64, "paths": 4, "max_memory_mb": 2.5}),
        ((300, 500), {"num_disparities": 96, "paths": 8, "block_size": 1, "max_memory_mb": 5}),
        ((300, 500), {"num_disparities": 96, "paths": 8, "threads": 1, "max_memory_mb": 5}),
    ],
)
@pytest.mark.parametrize("stacked", [True, False], ids=["stack", "frame"])
def test_semi_global_memory_is_refused_when_built(
    frame: tuple[int, ...], params: dict[str, Any], stacked: bool
) -> None:
    # The lazy array was built; the ValueError came from the worker at compute time.
    a = (
        da.zeros((4, *frame), dtype=np.uint8, chunks=(1, *frame))
        if stacked
        else da.zeros(frame, dtype=np.uint8)
    )
    image = np.zeros(frame, np.uint8)
    assert_same_error(
        lambda: sdd.semi_global_match(a, a, **params),
        lambda: stereodepth.semi_global_match(image, image, **params),
    )


def test_semi_global_memory_within_the_limit_builds_and_matches() -> None:
    left = np.random.default_rng(0).integers(0, 256, (2, 40, 60), dtype=np.uint8)
    right = np.roll(left, -3, axis=2)
    params = {"num_disparities": 16, "paths": 8, "max_memory_mb": 1}
    lazy = sdd.semi_global_match(
        da.from_array(left, chunks=(1, 40, 60)), da.from_array(right, chunks=(1, 40, 60)), **params
    )
    want = np.stack([stereodepth.semi_global_match(left[i], right[i], **params) for i in range(2)])
    np.testing.assert_array_equal(lazy.compute(scheduler="threads"), want, strict=True)


def test_semi_global_memory_without_threads_is_checked_for_one_thread() -> None:
    # threads=None is every core of the machine that matches, which the client does not know:
    # what one thread needs is refused now (above), a worker's own figure by the worker.
    a = da.zeros((4, 400, 600), dtype=np.uint8, chunks=(1, 400, 600))
    one = memory_estimate((400, 600), num_disparities=128, paths=3, threads=1) / 2**20
    limit = one * 1.01
    assert sdd.semi_global_match(a, a, num_disparities=128, paths=3, max_memory_mb=limit).shape
    with pytest.raises(ValueError, match=r"^semi-global matching of a 600x400 px pair .* needs"):
        sdd.semi_global_match(a, a, num_disparities=128, paths=3, max_memory_mb=one * 0.99)


@pytest.mark.parametrize(
    "frame", [(0, 30), (30, 0), (0, 0), (0, 30, 3), (30, 0, 3)], ids=lambda s: "x".join(map(str, s))
)
@pytest.mark.parametrize("stacked", [True, False], ids=["stack", "frame"])
@pytest.mark.parametrize("method", ["block_match", "semi_global_match"])
def test_empty_frames_are_refused_when_built(
    frame: tuple[int, ...], stacked: bool, method: str
) -> None:
    a = da.zeros((2, *frame) if stacked else frame, dtype=np.uint8)
    image = np.zeros(frame, np.uint8)
    assert_same_error(
        lambda: getattr(sdd, method)(a, a, num_disparities=16),
        lambda: getattr(stereodepth, method)(image, image, num_disparities=16),
    )


def test_empty_uint16_frames_with_an_intensity_range_are_refused_when_built() -> None:
    a = da.zeros((3, 20, 0), dtype=np.uint16)
    image = np.zeros((20, 0), np.uint16)
    params = {"num_disparities": 16, "intensity_range": (0, 4095)}
    assert_same_error(
        lambda: sdd.block_match(a, a, **params),
        lambda: stereodepth.block_match(image, image, **params),
    )


@pytest.mark.parametrize("method", ["block_match", "semi_global_match"])
def test_an_empty_uint8_frame_is_named_before_the_intensity_range(method: str) -> None:
    # the numpy function's order: the pair's shape, then intensity_range against its dtype
    a = da.zeros((2, 0, 30), dtype=np.uint8)
    image = np.zeros((0, 30), np.uint8)
    params = {"num_disparities": 16, "intensity_range": (0, 255)}
    assert_same_error(
        lambda: getattr(sdd, method)(a, a, **params),
        lambda: getattr(stereodepth, method)(image, image, **params),
    )


@pytest.mark.parametrize(
    ("num_disparities", "cols"),
    [
        (16, 2**26),  # the product reaches 2**30
        (4096, 2**18),
        (8, 2**27),
        (600, 2**30 // 600 + 1),
        # 20 x cols is below 2**30, but the limit rounds the disparities up to 16, the
        # widest kernels' lanes, on every ISA, and 32 x cols is not
        (20, 2**30 // 24 + 1),
        # 24 x cols is below 2**30 and passed this check (8 lanes): a baseline worker matched
        # it and an AVX2 one refused it; every ISA refuses it now, so the graph is refused
        (24, 2**30 // 24),
    ],
)
@pytest.mark.parametrize("rgb", [False, True], ids=["grey", "rgb"])
def test_block_match_width_times_disparities_is_refused_when_built(
    num_disparities: int, cols: int, rgb: bool
) -> None:
    frame = (2, cols, 3) if rgb else (2, cols)
    a = da.zeros((3, *frame), dtype=np.uint8, chunks=(1, *frame))
    image = np.zeros(frame, np.uint8)  # zero pages: refused before anything is read
    assert_same_error(
        lambda: sdd.block_match(a, a, num_disparities=num_disparities),
        lambda: stereodepth.block_match(image, image, num_disparities=num_disparities),
    )


@pytest.mark.parametrize(("num_disparities", "cols"), [(16, 2**26 - 1), (24, 2**25 - 1)])
def test_block_match_just_inside_the_width_limit_builds(num_disparities: int, cols: int) -> None:
    # (24, 2**25 - 1): 24 rounds up to 32, and 32 x cols is just below 2**30
    a = da.zeros((3, 2, cols), dtype=np.uint8, chunks=(1, 2, cols))
    lazy = sdd.block_match(a, a, num_disparities=num_disparities)
    assert lazy.shape == (3, 2, cols)


@pytest.mark.parametrize("shape", [(2, 2, 2, 2), (5,), (), (3, 1, 4, 1, 5)], ids=str)
@pytest.mark.parametrize("function", ["disparity_to_depth", "reproject"])
def test_disparity_shape_errors_name_the_users_shape(shape: tuple[int, ...], function: str) -> None:
    # disparity_to_depth said "got (1, 1, 1, 1)", the shape of its internal probe
    d = np.ones(shape, np.float32)
    assert_same_error(
        lambda: getattr(sdd, function)(da.from_array(d), **RIG),
        lambda: getattr(stereodepth, function)(d, **RIG),
    )


def test_disparity_shape_error_with_unknown_chunk_sizes_shows_them() -> None:
    d = da.ones((4, 2, 2, 2), dtype=np.float32, chunks=(1, 2, 2, 2))
    keep = da.from_array(np.array([True, False, True, True]), chunks=1)
    message = r"^disparity must have shape \(H, W\) or \(N, H, W\), got \(nan, 2, 2, 2\)$"
    with pytest.raises(ValueError, match=message):
        sdd.disparity_to_depth(d[keep], **RIG)


@pytest.mark.parametrize("function", ["disparity_to_depth", "reproject"])
def test_disparity_dtype_errors_are_the_numpy_ones(function: str) -> None:
    d = np.ones((3, 4), np.int32)
    assert_same_error(
        lambda: getattr(sdd, function)(da.from_array(d), **RIG),
        lambda: getattr(stereodepth, function)(d, **RIG),
    )


def test_disparity_to_depth_options_still_checked_when_built() -> None:
    d = np.ones((2, 3, 4), np.uint16)
    assert_same_error(
        lambda: sdd.disparity_to_depth(da.from_array(d), **RIG),
        lambda: stereodepth.disparity_to_depth(d, **RIG),
    )  # uint16 needs scale
    assert_same_error(
        lambda: sdd.disparity_to_depth(da.from_array(d), **RIG, scale=1 / 256, dtype=np.int8),
        lambda: stereodepth.disparity_to_depth(d, **RIG, scale=1 / 256, dtype=np.int8),
    )


def test_reproject_builds_without_a_frames_work() -> None:
    # The probe was a whole frame (float32 points of 12 bytes per pixel: 48 MB here, 768 MB
    # at 8000x8000), reprojected on the client while the graph was built.
    d = da.zeros((2, 2000, 2000), dtype=np.float32, chunks=(1, -1, -1))
    tracemalloc.start()
    try:
        lazy = sdd.reproject(d, **RIG)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert lazy.shape == (2, 2000, 2000, 3)
    assert peak < 1_000_000


def test_reproject_default_centre_is_the_frames_and_options_are_checked() -> None:
    d = (np.random.default_rng(3).random((3, 9, 14)) * 20).astype(np.float32)
    lazy = sdd.reproject(da.from_array(d, chunks=(2, 4, 5)), **RIG, max_depth_m=40.0)
    np.testing.assert_array_equal(
        lazy.compute(scheduler="threads"),
        stereodepth.reproject(d, **RIG, max_depth_m=40.0),
        strict=True,
    )
    assert_same_error(
        lambda: sdd.reproject(da.from_array(d), **RIG, cx_px=float("nan")),
        lambda: stereodepth.reproject(d, **RIG, cx_px=float("nan")),
    )
    assert_same_error(
        lambda: sdd.reproject(da.from_array(d), **RIG, min_depth_m=5.0, max_depth_m=1.0),
        lambda: stereodepth.reproject(d, **RIG, min_depth_m=5.0, max_depth_m=1.0),
    )


@pytest.mark.parametrize(
    ("left_dtype", "right_dtype"),
    [("float32", "float32"), ("uint8", "float64"), ("int16", "uint8"), ("bool", "bool")],
)
@pytest.mark.parametrize("method", ["block_match", "semi_global_match"])
def test_image_dtype_errors_are_the_numpy_ones(
    left_dtype: str, right_dtype: str, method: str
) -> None:
    # "left must be uint8 or uint16 images", and a float right image was "left and right must
    # have the same dtype": the numpy function names the image and its rule
    left, right = np.zeros((6, 8), left_dtype), np.zeros((6, 8), right_dtype)
    assert_same_error(
        lambda: getattr(sdd, method)(da.from_array(left), da.from_array(right), num_disparities=16),
        lambda: getattr(stereodepth, method)(left, right, num_disparities=16),
    )
