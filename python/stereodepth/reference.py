"""Pure-numpy reference implementations of the native kernels: the correctness oracle.

Each function has the signature and the documented behaviour of its native counterpart and
follows the same arithmetic step by step, written for clarity rather than speed. Tests compare
the two; benchmarks time them side by side.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _validate as check
from ._reference_block_match import block_match  # the oracle's body lives there
from .depth import DepthOptions, as_disparity, prepare_out

__all__ = ["block_match", "disparity_to_depth", "reproject"]


def disparity_to_depth(
    disparity: Any,
    *,
    focal_px: float,
    baseline_m: float,
    doffs_px: float = 0.0,
    scale: float | None = None,
    dtype: Any = np.float32,
    min_depth_m: float | None = None,
    max_depth_m: float | None = None,
    invalid_value: float | None = None,
    min_disparity: int | None = None,
    out: np.ndarray | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Oracle of :func:`stereodepth.disparity_to_depth` (``threads`` is checked, then unused)."""
    arr = as_disparity(disparity)
    o = DepthOptions(
        arr,
        focal_px=focal_px,
        baseline_m=baseline_m,
        doffs_px=doffs_px,
        scale=scale,
        dtype=dtype,
        min_depth_m=min_depth_m,
        max_depth_m=max_depth_m,
        invalid_value=invalid_value,
        min_disparity=min_disparity,
    )
    check.threads(threads)
    result = prepare_out(out, arr, o.dtype)
    k = o.focal_px * o.baseline_m

    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if o.dtype == np.float32 and arr.dtype != np.float64:
            # float32 arithmetic, one rounding per operation, as the kernel does.
            d = arr.astype(np.float32)
            den = d * np.float32(o.scale) + np.float32(o.doffs_px)
            z = np.float32(k) / den
            ok = (den > 0) & (z >= np.float32(o.min_depth_m)) & (z <= np.float32(o.max_depth_m))
            if o.invalid_value is not None:
                ok &= d != np.float32(o.invalid_value)
            if o.invalid_below is not None:
                ok &= d >= np.float32(o.invalid_below)
            depth = np.where(ok, z, np.float32(np.nan))
        else:
            # float64 arithmetic (float64 input, or millimetre output).
            d = arr.astype(np.float64)
            den = d * o.scale + o.doffs_px
            z = k / den
            if o.dtype == np.float32:
                zf = z.astype(np.float32)
                ok = (
                    (den > 0)
                    & (zf >= np.float32(o.min_depth_m))
                    & (zf <= np.float32(o.max_depth_m))
                )
            else:
                ok = (den > 0) & (z >= o.min_depth_m) & (z <= o.max_depth_m)
            if o.invalid_value is not None:
                ok &= d != o.invalid_value
            if o.invalid_below is not None:
                ok &= d >= o.invalid_below
            if o.dtype == np.float32:
                depth = np.where(ok, zf, np.float32(np.nan))
            else:
                mm = np.minimum(np.rint(np.where(ok, z, 0.0) * 1000.0), 65535.0)
                depth = np.where(ok, mm, 0).astype(np.uint16)
    result[...] = depth
    return result


def reproject(
    disparity: Any,
    *,
    Q: Any = None,
    focal_px: float | None = None,
    baseline_m: float | None = None,
    cx_px: float | None = None,
    cy_px: float | None = None,
    doffs_px: float | None = None,
    scale: float | None = None,
    min_depth_m: float | None = None,
    max_depth_m: float | None = None,
    invalid_value: float | None = None,
    min_disparity: int | None = None,
    out: np.ndarray | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Oracle of :func:`stereodepth.reproject` (``threads`` is checked, then unused)."""
    from .pointcloud import ReprojectOptions, prepare_points_out

    arr = as_disparity(disparity)
    o = ReprojectOptions(
        arr,
        Q=Q,
        focal_px=focal_px,
        baseline_m=baseline_m,
        cx_px=cx_px,
        cy_px=cy_px,
        doffs_px=doffs_px,
        scale=scale,
        min_depth_m=min_depth_m,
        max_depth_m=max_depth_m,
        invalid_value=invalid_value,
        min_disparity=min_disparity,
    )
    check.threads(threads)
    result = prepare_points_out(out, arr)
    q = o.Q
    rows, cols = arr.shape[-2:]
    raw = arr.astype(np.float64)  # exact for every accepted dtype
    x = np.arange(cols, dtype=np.float64)
    y = np.arange(rows, dtype=np.float64)[:, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        d = raw * o.scale
        # Float64, one rounding per operation, in the kernel's order.
        w = (q[3, 0] * x + q[3, 2] * d) + (q[3, 1] * y + q[3, 3])
        iw = 1.0 / w
        xyz = [
            (((q[i, 0] * x + q[i, 2] * d) + (q[i, 1] * y + q[i, 3])) * iw).astype(np.float32)
            for i in range(3)
        ]
        px, py, pz = xyz
        ok = (
            np.isfinite(px)
            & np.isfinite(py)
            & (pz > 0)
            & (pz >= np.float32(o.min_depth_m))
            & (pz <= np.float32(o.max_depth_m))
        )
    if o.invalid_value is not None:
        # compared in float32, or float64 for float64 input, as disparity_to_depth does
        if arr.dtype == np.float64:
            ok &= raw != o.invalid_value
        else:
            ok &= arr.astype(np.float32) != np.float32(o.invalid_value)
    if o.invalid_below is not None:
        ok &= raw >= o.invalid_below
    for i, c in enumerate(xyz):
        result[..., i] = np.where(ok, c, np.float32(np.nan))
    return result
