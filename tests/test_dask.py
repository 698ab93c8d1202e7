"""stereodepth.dask: the kernels over dask arrays equal the numpy functions frame by frame, bit
for bit, on any chunking, from memory-mapped stacks and on a real LocalCluster."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import matching
from stereodepth.semi_global import DEFAULT_P2

da = pytest.importorskip("dask.array")
sdd = pytest.importorskip("stereodepth.dask")

RIG = {"focal_px": 718.856, "baseline_m": 0.537166}
N, H, W = 5, 36, 50


def stack(seed: int = 0, *, rgb: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """N random-dot pairs, pair i shifted by 2 + i pixels."""
    rng = np.random.default_rng(seed)
    left = rng.integers(0, 256, (N, H, W, 3) if rgb else (N, H, W), dtype=np.uint8)
    right = np.stack([np.roll(left[i], -(2 + i), axis=1) for i in range(N)])
    return left, right


def disparities(seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = (rng.random((N, H, W)) * 60).astype(np.float32)
    d[rng.random(d.shape) < 0.1] = np.nan
    return d


def assert_same(a: Any, b: np.ndarray) -> None:
    np.testing.assert_array_equal(np.asarray(a), b, strict=True)


@pytest.mark.parametrize("chunks", [(1, H, W), (2, 7, 13), (N, H, W)])
@pytest.mark.parametrize("dtype", [np.float32, np.uint16])
def test_disparity_to_depth_equals_numpy(chunks: tuple[int, ...], dtype: type) -> None:
    d = disparities()
    lazy = sdd.disparity_to_depth(
        da.from_array(d, chunks=chunks), **RIG, dtype=dtype, max_depth_m=60.0
    )
    assert lazy.dtype == dtype and lazy.chunks == da.from_array(d, chunks=chunks).chunks
    want = stereodepth.disparity_to_depth(d, **RIG, dtype=dtype, max_depth_m=60.0)
    assert_same(lazy.compute(scheduler="threads"), want)
    assert_same(
        sdd.disparity_to_depth(da.from_array(d[0]), **RIG).compute(),
        stereodepth.disparity_to_depth(d[0], **RIG),
    )


def test_a_stack_larger_than_one_chunk_from_memory_mapped_files(tmp_path: Path) -> None:
    """The out-of-core path: read frame by frame from .npy files, write frame by frame."""
    d = disparities(2)
    np.save(tmp_path / "disparity.npy", d)
    src = np.load(tmp_path / "disparity.npy", mmap_mode="r")
    dst = np.lib.format.open_memmap(
        tmp_path / "depth.npy", mode="w+", dtype=np.float32, shape=d.shape
    )
    depth = sdd.disparity_to_depth(da.from_array(src, chunks=(1, H, W)), **RIG)
    da.store(depth, dst, scheduler="threads")
    dst.flush()
    del dst
    assert_same(np.load(tmp_path / "depth.npy"), stereodepth.disparity_to_depth(d, **RIG))


@pytest.mark.parametrize("rgb", [False, True], ids=["grey", "rgb"])
@pytest.mark.parametrize("chunks", ["frame", "split"])
def test_block_match_equals_numpy_frame_by_frame(rgb: bool, chunks: str) -> None:
    left, right = stack(3, rgb=rgb)
    if chunks == "frame":
        c: tuple[int, ...] = (1, H, W, 3) if rgb else (1, H, W)
    else:  # frames split across chunks: rechunked to whole frames
        c = (2, 11, 17, 3) if rgb else (2, 11, 17)
    lazy = sdd.block_match(
        da.from_array(left, chunks=c),
        da.from_array(right, chunks=c),
        num_disparities=16,
        block_size=7,
    )
    assert lazy.shape == (N, H, W) and lazy.dtype == np.float32
    assert all(len(ch) == 1 for ch in lazy.chunks[1:])
    got = lazy.compute(scheduler="threads")
    for i in range(N):
        want = matching.block_match(left[i], right[i], num_disparities=16, block_size=7)
        assert_same(got[i], want)
        assert np.nanmedian(got[i]) == pytest.approx(2 + i, abs=0.05)
    one = sdd.block_match(
        da.from_array(left[0]), da.from_array(right[0]), num_disparities=16, block_size=7
    )
    assert_same(one.compute(), got[0])


@pytest.mark.parametrize("rgb", [False, True], ids=["grey", "rgb"])
@pytest.mark.parametrize("chunks", ["frame", "split"])
def test_semi_global_match_equals_numpy_frame_by_frame(rgb: bool, chunks: str) -> None:
    left, right = stack(7, rgb=rgb)
    if chunks == "frame":
        c: tuple[int, ...] = (1, H, W, 3) if rgb else (1, H, W)
    else:  # frames split across chunks: rechunked to whole frames
        c = (2, 11, 17, 3) if rgb else (2, 11, 17)
    params = {"num_disparities": 16, "paths": 8, "p2": 300, "fill": True}
    lazy = sdd.semi_global_match(
        da.from_array(left, chunks=c), da.from_array(right, chunks=c), **params
    )
    assert lazy.shape == (N, H, W) and lazy.dtype == np.float32
    assert all(len(ch) == 1 for ch in lazy.chunks[1:])
    got = lazy.compute(scheduler="threads")
    for i in range(N):
        want = stereodepth.semi_global_match(left[i], right[i], **params)
        assert_same(got[i], want)
        assert np.nanmedian(got[i]) == pytest.approx(2 + i, abs=0.05)
    one = sdd.semi_global_match(da.from_array(left[0]), da.from_array(right[0]), **params)
    assert_same(one.compute(), got[0])


def test_semi_global_match_of_uint16_frames_with_one_intensity_range() -> None:
    left, right = stack(8)
    left16, right16 = left.astype(np.uint16) * 16 + 100, right.astype(np.uint16) * 16 + 100
    params = {"num_disparities": 16, "intensity_range": (0, 4095)}
    got = sdd.semi_global_match(
        da.from_array(left16, chunks=(2, H, W)), da.from_array(right16, chunks=(2, H, W)), **params
    ).compute(scheduler="threads")
    want = [stereodepth.semi_global_match(left16[i], right16[i], **params) for i in range(N)]
    assert_same(got, np.stack(want))


def test_reproject_equals_numpy() -> None:
    d = disparities(4)
    rig = {**RIG, "cx_px": 24.5, "cy_px": 17.0}
    lazy = sdd.reproject(da.from_array(d, chunks=(2, 9, 50)), **rig)
    assert lazy.shape == (N, H, W, 3) and lazy.chunks[1:] == ((H,), (W,), (3,))
    assert_same(lazy.compute(scheduler="threads"), stereodepth.reproject(d, **rig))
    assert_same(
        sdd.reproject(da.from_array(d[1]), **RIG).compute(), stereodepth.reproject(d[1], **RIG)
    )


def test_the_whole_chain_is_lazy_and_checked_up_front() -> None:
    left, right = stack(5)
    calls: list[int] = []
    lazy_left = da.from_array(left, chunks=(1, H, W)).map_blocks(
        lambda b: calls.append(1) or b, dtype=np.uint8, meta=np.empty((0, 0, 0), np.uint8)
    )
    disparity = sdd.block_match(
        lazy_left, da.from_array(right, chunks=(1, H, W)), num_disparities=16
    )
    depth = sdd.disparity_to_depth(disparity, **RIG)
    assert calls == []  # nothing ran yet
    got = depth.compute(scheduler="synchronous")
    assert len(calls) == N
    want = [
        stereodepth.disparity_to_depth(
            matching.block_match(left[i], right[i], num_disparities=16), **RIG
        )
        for i in range(N)
    ]
    assert_same(got, np.stack(want))


@pytest.mark.parametrize(
    ("call", "exc", "message"),
    [
        (
            lambda: sdd.disparity_to_depth(np.ones((2, 2), np.float32), **RIG),
            TypeError,
            "disparity must be a dask.array.Array .* got ndarray",
        ),
        (
            lambda: sdd.disparity_to_depth(
                da.ones((2, 2), dtype=np.float32), focal_px=1.0, baseline_m=-1.0
            ),
            ValueError,
            "baseline_m must be a finite number > 0, got -1.0",
        ),
        (
            lambda: sdd.disparity_to_depth(da.ones((2, 2), dtype=np.uint8), **RIG),
            TypeError,
            "disparity must have dtype float16",
        ),
        (
            lambda: sdd.disparity_to_depth(da.ones((2, 2), dtype=np.float32), **RIG, colour=1),
            TypeError,
            "unexpected keyword argument 'colour'",
        ),
        (
            lambda: sdd.disparity_to_depth(
                da.ones((2, 2), dtype=np.float32), **RIG, out=np.empty((2, 2), np.float32)
            ),
            TypeError,
            "out is not accepted for dask arrays",
        ),
        (
            lambda: sdd.block_match(
                da.ones((2, 8, 8), dtype=np.uint8),
                da.ones((2, 8, 9), dtype=np.uint8),
                num_disparities=4,
            ),
            ValueError,
            r"left and right must have the same shape, got \(2, 8, 8\) and \(2, 8, 9\)",
        ),
        (
            lambda: sdd.block_match(
                da.ones((8, 8), dtype=np.uint8), da.ones((8, 8), dtype=np.uint16), num_disparities=4
            ),
            TypeError,
            "left and right must have the same dtype, got uint8 and uint16",
        ),
        (
            lambda: sdd.block_match(
                da.ones((8, 8), dtype=np.float32),
                da.ones((8, 8), dtype=np.float32),
                num_disparities=4,
            ),
            TypeError,
            r"^left must be 2-D uint8 or uint16 grey, or \(H, W, 3\) uint8 RGB, got dtype float32$",
        ),
        (
            lambda: sdd.block_match(
                da.ones((2, 8, 8, 4), dtype=np.uint8),
                da.ones((2, 8, 8, 4), dtype=np.uint8),
                num_disparities=4,
            ),
            ValueError,
            r"left must have shape .* got \(2, 8, 8, 4\) uint8",
        ),
        # One colour frame, as the numpy function reads it: (H, W, 4) RGBA and (H, W, 3)
        # uint16 were matched as 8 grey frames 4 or 3 px wide, without a word.
        (
            lambda: sdd.block_match(
                da.ones((8, 8, 4), dtype=np.uint8),
                da.ones((8, 8, 4), dtype=np.uint8),
                num_disparities=4,
            ),
            ValueError,
            r"left must have shape .* got \(8, 8, 4\) uint8 \(a last axis of 3 or 4 is read as "
            "colour channels",
        ),
        (
            lambda: sdd.semi_global_match(
                da.ones((8, 8, 3), dtype=np.uint16),
                da.ones((8, 8, 3), dtype=np.uint16),
                num_disparities=16,
            ),
            ValueError,
            r"left must have shape .* got \(8, 8, 3\) uint16",
        ),
        (
            lambda: sdd.block_match(
                da.ones((8, 8), dtype=np.uint8), da.ones((8, 8), dtype=np.uint8)
            ),
            TypeError,
            "missing required keyword argument: 'num_disparities'",
        ),
        (
            lambda: sdd.block_match(
                da.ones((8, 8), dtype=np.uint8),
                da.ones((8, 8), dtype=np.uint8),
                num_disparities=4,
                block_size=4,
            ),
            ValueError,
            "block_size must be an odd integer",
        ),
        (
            lambda: sdd.block_match(
                da.ones((8, 8), dtype=np.uint8),
                da.ones((8, 8), dtype=np.uint8),
                num_disparities=4,
                return_confidence=True,
            ),
            TypeError,
            "return_confidence is not accepted for dask arrays",
        ),
        (
            lambda: sdd.reproject(da.ones((2, 2), dtype=np.float32), Q=np.eye(3)),
            ValueError,
            r"Q must be a 4x4 matrix",
        ),
        (
            lambda: sdd.reproject(da.ones((2, 2, 2, 2), dtype=np.float32), **RIG),
            ValueError,
            r"disparity must have shape \(H, W\) or \(N, H, W\), got \(2, 2, 2, 2\)",
        ),
        (
            lambda: sdd.semi_global_match(
                da.ones((4, 4), dtype=np.uint8), da.ones((4, 4), dtype=np.uint8)
            ),
            TypeError,
            r"semi_global_match\(\) missing required keyword argument: 'num_disparities'",
        ),
        (
            lambda: sdd.semi_global_match(
                da.ones((4, 4), dtype=np.uint8),
                da.ones((4, 4), dtype=np.uint8),
                num_disparities=16,
                p1=600,
            ),
            ValueError,
            rf"p2 must be an integer in \[p1, .*\] = \[600, .*got {DEFAULT_P2}\b",
        ),
        (
            lambda: sdd.semi_global_match(
                da.ones((4, 4), dtype=np.uint8),
                da.ones((4, 4), dtype=np.uint8),
                num_disparities=16,
                paths=5,
            ),
            ValueError,
            "paths must be 3, 4 or 8, got 5",
        ),
        (
            lambda: sdd.semi_global_match(
                da.ones((4, 4), dtype=np.uint8),
                da.ones((4, 4), dtype=np.uint8),
                num_disparities=16,
                cost="sad",
            ),
            TypeError,
            r"^semi_global_match\(\) got an unexpected keyword argument 'cost'$",
        ),
        (
            lambda: sdd.block_match(
                da.ones((4, 4), dtype=np.uint8),
                da.ones((4, 4), dtype=np.uint8),
                num_disparities=16,
                p1=3,
            ),
            TypeError,
            r"^block_match\(\) got an unexpected keyword argument 'p1'$",
        ),
        (
            lambda: sdd.semi_global_match(
                da.ones((4, 4), dtype=np.uint8),
                da.ones((4, 4), dtype=np.uint8),
                num_disparities=16,
                return_confidence=True,
            ),
            TypeError,
            "return_confidence is not accepted for dask arrays",
        ),
        (
            lambda: sdd.semi_global_match(
                da.ones((4, 4), dtype=np.uint8), da.ones((4, 5), dtype=np.uint8), num_disparities=16
            ),
            ValueError,
            r"left and right must have the same shape, got \(4, 4\) and \(4, 5\)",
        ),
        (
            lambda: sdd.semi_global_match(
                da.ones((4, 4), dtype=np.float32),
                da.ones((4, 4), dtype=np.float32),
                num_disparities=16,
            ),
            TypeError,
            r"^left must be 2-D uint8 or uint16 grey, or \(H, W, 3\) uint8 RGB, got dtype float32$",
        ),
        (
            lambda: sdd.semi_global_match(
                np.ones((4, 4), np.uint8), da.ones((4, 4), dtype=np.uint8), num_disparities=16
            ),
            TypeError,
            "left must be a dask.array.Array .* got ndarray",
        ),
    ],
)
def test_rejects_bad_input_before_computing(call: Any, exc: type, message: str) -> None:
    with pytest.raises(exc, match=message):
        call()


def test_unknown_chunk_sizes_are_named_not_called_a_shape_mismatch() -> None:
    # After boolean indexing the shape holds NaN: the matchers said "left and right must have
    # the same shape, got (nan, 36, 50) and (nan, 36, 50)", and reproject of a (nan, W) map
    # raised numpy's "'float' object cannot be interpreted as an integer" from its probe.
    left, right = (da.from_array(a, chunks=(1, -1, -1)) for a in stack())
    keep = da.from_array(np.array([True, False, True, True, False]), chunks=1)
    for f in (sdd.block_match, sdd.semi_global_match):
        with pytest.raises(ValueError, match=r"^left must have a known shape, got \(nan, 36, 50\)"):
            f(left[keep], right[keep], num_disparities=16)
    d = da.from_array(disparities()[0], chunks=(6, -1))
    rows = da.from_array(np.arange(H) % 2 == 0, chunks=6)
    with pytest.raises(ValueError, match=r"disparity must have a known shape.*compute_chunk_sizes"):
        sdd.reproject(d[rows], **RIG)
    known = left[keep].compute_chunk_sizes(), right[keep].compute_chunk_sizes()
    assert sdd.block_match(*known, num_disparities=16).shape == (3, H, W)


@pytest.mark.cluster
def test_on_a_local_cluster() -> None:
    distributed = pytest.importorskip("distributed")
    left, right = stack(6, rgb=True)
    # dashboard_address: a free loopback port (None would still try 8787, and warn if taken)
    with (
        distributed.LocalCluster(
            n_workers=2,
            processes=True,
            threads_per_worker=1,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        disparity = sdd.block_match(
            da.from_array(left, chunks=(1, H, W, 3)),
            da.from_array(right, chunks=(1, H, W, 3)),
            num_disparities=16,
        )
        depth = sdd.disparity_to_depth(disparity, **RIG, dtype=np.uint16)
        got = client.compute(depth).result()
        sgm = sdd.semi_global_match(
            da.from_array(left, chunks=(2, H, W, 3)),
            da.from_array(right, chunks=(2, H, W, 3)),
            num_disparities=16,
            paths=4,
        )
        got_sgm = client.compute(sgm).result()
    want = [
        stereodepth.disparity_to_depth(
            matching.block_match(left[i], right[i], num_disparities=16), **RIG, dtype=np.uint16
        )
        for i in range(N)
    ]
    assert_same(got, np.stack(want))
    want_sgm = [
        stereodepth.semi_global_match(left[i], right[i], num_disparities=16, paths=4)
        for i in range(N)
    ]
    assert_same(got_sgm, np.stack(want_sgm))
