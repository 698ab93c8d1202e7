"""Disparity to depth on 8 x 1920 x 1080 maps: native vs the oracle, the numpy one-liner and
np.copyto of the same bytes (the memory-bandwidth bound). Each benchmark checks its result.

    pytest bench/bench_depth.py
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import reference

FOCAL_PX, BASELINE_M = 718.856, 0.537166
K = FOCAL_PX * BASELINE_M
SHAPE = (8, 1080, 1920)


def make_disparity(dtype: type) -> np.ndarray:
    rng = np.random.default_rng(0)
    d = rng.random(SHAPE, dtype=np.float32) * 200
    d[rng.random(SHAPE) < 0.05] = 0.0  # holes
    if dtype == np.int16:
        return np.round(d * 16).astype(np.int16)
    return d.astype(dtype)


CASES = [
    (np.float32, np.float32),
    (np.float32, np.uint16),
    (np.int16, np.float32),
    (np.int16, np.uint16),
]


def case_id(c: tuple[type, type]) -> str:
    return f"{np.dtype(c[0]).name}_to_{np.dtype(c[1]).name}"


@pytest.fixture(scope="module", params=CASES, ids=case_id)
def case(request: Any) -> tuple[np.ndarray, np.ndarray, np.dtype]:
    in_dtype, out_dtype = request.param
    d = make_disparity(in_dtype)
    want = reference.disparity_to_depth(
        d, focal_px=FOCAL_PX, baseline_m=BASELINE_M, dtype=out_dtype
    )
    return d, want, np.dtype(out_dtype)


def numpy_one_liner(d: np.ndarray, out_dtype: np.dtype) -> np.ndarray:
    """What people write today."""
    with np.errstate(divide="ignore", invalid="ignore"):
        if d.dtype == np.int16:
            d = d / 16.0
        if out_dtype == np.uint16:
            return np.where(d > 0, np.minimum(np.rint(K * 1000 / d), 65535), 0).astype(np.uint16)
        return np.where(d > 0, K / d, np.nan).astype(np.float32)


def group(benchmark: Any, c: tuple[np.ndarray, np.ndarray, np.dtype]) -> None:
    benchmark.group = f"disparity_to_depth {c[0].dtype}->{c[2].name} {SHAPE}"


def test_stereodepth(benchmark: Any, impl: Any, case: Any) -> None:
    d, want, out_dtype = case
    group(benchmark, case)
    impl("stereodepth")
    out = np.empty(d.shape, out_dtype)
    benchmark(
        stereodepth.disparity_to_depth,
        d,
        focal_px=FOCAL_PX,
        baseline_m=BASELINE_M,
        dtype=out_dtype,
        out=out,
    )
    np.testing.assert_array_equal(out, want)


def test_stereodepth_one_thread(benchmark: Any, impl: Any, case: Any) -> None:
    d, want, out_dtype = case
    group(benchmark, case)
    impl("stereodepth threads=1")
    out = np.empty(d.shape, out_dtype)
    benchmark(
        stereodepth.disparity_to_depth,
        d,
        focal_px=FOCAL_PX,
        baseline_m=BASELINE_M,
        dtype=out_dtype,
        out=out,
        threads=1,
    )
    np.testing.assert_array_equal(out, want)


def test_oracle(benchmark: Any, impl: Any, case: Any) -> None:
    d, want, out_dtype = case
    group(benchmark, case)
    impl("oracle (stereodepth.reference)")
    got = benchmark.pedantic(
        reference.disparity_to_depth,
        args=(d,),
        kwargs={"focal_px": FOCAL_PX, "baseline_m": BASELINE_M, "dtype": out_dtype},
        rounds=3,
        iterations=1,
    )
    np.testing.assert_array_equal(got, want)


def test_numpy_one_liner(benchmark: Any, impl: Any, case: Any) -> None:
    d, want, out_dtype = case
    group(benchmark, case)
    impl("numpy np.where(d > 0, k / d, nan)")
    got = benchmark.pedantic(numpy_one_liner, args=(d, out_dtype), rounds=5, iterations=1)
    valid = (want > 0) if out_dtype == np.uint16 else np.isfinite(want)
    if out_dtype == np.float32:
        np.testing.assert_allclose(got[valid], want[valid], rtol=1e-6)
    else:
        assert np.abs(got[valid].astype(int) - want[valid]).max() <= 1


def test_memory_bound_copyto(benchmark: Any, impl: Any, case: Any) -> None:
    d, _, out_dtype = case
    group(benchmark, case)
    impl("np.copyto (memory bound)")
    src = d.view(np.uint8).reshape(d.shape[0], -1)
    dst = np.empty((d.shape[0], d.shape[1] * d.shape[2] * out_dtype.itemsize), np.uint8)
    # Read the input's bytes, write the output's bytes: the least any conversion must move.
    n = min(src.shape[1], dst.shape[1])
    benchmark(np.copyto, dst[:, :n], src[:, :n])
    assert np.array_equal(dst[:, :n], src[:, :n])
