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

__all__ = [
    "block_match",
    "disparity_to_depth",
    "init_undistort_rectify_map",
    "remap",
    "reproject",
]


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
            if o.negative_invalid:
                ok &= d >= 0
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
            if o.negative_invalid:
                ok &= d >= 0
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
    if o.negative_invalid:
        ok &= raw >= 0
    for i, c in enumerate(xyz):
        result[..., i] = np.where(ok, c, np.float32(np.nan))
    return result


def init_undistort_rectify_map(
    K: Any,
    D: Any,
    R: Any,
    P: Any,
    size: tuple[int, int],
    model: str = "plumb_bob",
    *,
    threads: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Oracle of :func:`stereodepth.init_undistort_rectify_map`: the same float64 operations
    in the same order, rounded once to float32 (``threads`` is checked, then unused)."""
    from .rectify import _camera_matrix, _distortion, _model, _real_matrix, _rotation, _size

    m = _model("model", model)
    k_mat = _camera_matrix("K", K)
    d = np.zeros(8)
    coeffs = _distortion("D", D, m)
    d[: coeffs.size] = coeffs
    rot = np.eye(3) if R is None else _rotation("R", R)
    p = check.real_array("P", P)
    p = _real_matrix("P", p[:, :3] if p.shape == (3, 4) else p, (3, 3))
    width, height = _size("size", size)
    check.threads(threads)
    a = [[float(_sum3(p[i], rot[:, j])) for j in range(3)] for i in range(3)]
    ir = _inverse3(a)
    j = np.arange(width, dtype=np.float64)[None, :]
    i = np.arange(height, dtype=np.float64)[:, None]
    big_x = ir[0][0] * j + ir[0][1] * i + ir[0][2]
    big_y = ir[1][0] * j + ir[1][1] * i + ir[1][2]
    big_w = ir[2][0] * j + ir[2][1] * i + ir[2][2]
    fx, fy, u0, v0 = k_mat[0, 0], k_mat[1, 1], k_mat[0, 2], k_mat[1, 2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if m == "equidistant":
            x = big_x / big_w
            y = big_y / big_w
            r = np.sqrt(x * x + y * y)
            theta = np.arctan(r)
            t2 = theta * theta
            t4 = t2 * t2
            t6 = t4 * t2
            t8 = t4 * t4
            theta_d = theta * ((((1 + d[0] * t2) + d[1] * t4) + d[2] * t6) + d[3] * t8)
            scale = np.where(r == 0, 1.0, theta_d / r)
            u = fx * x * scale + u0
            v = fy * y * scale + v0
            behind = ~(big_w > 0)
            u = np.where(behind, -1e6, u)
            v = np.where(behind, -1e6, v)
        else:
            w = 1.0 / big_w
            x = big_x * w
            y = big_y * w
            x2 = x * x
            y2 = y * y
            r2 = x2 + y2
            xy2 = 2 * x * y
            kr = (1 + ((d[4] * r2 + d[1]) * r2 + d[0]) * r2) / (
                1 + ((d[7] * r2 + d[6]) * r2 + d[5]) * r2
            )
            xd = x * kr + d[2] * xy2 + d[3] * (r2 + 2 * x2)
            yd = y * kr + d[2] * (r2 + 2 * y2) + d[3] * xy2
            u = fx * xd + u0
            v = fy * yd + v0
    return u.astype(np.float32), v.astype(np.float32)


def _sum3(a: np.ndarray, b: np.ndarray) -> float:
    """a[0] * b[0] + a[1] * b[1] + a[2] * b[2], left to right (the kernels' order)."""
    return float(a[0]) * float(b[0]) + float(a[1]) * float(b[1]) + float(a[2]) * float(b[2])


def _inverse3(a: list[list[float]]) -> list[list[float]]:
    """The 3x3 inverse by cofactors, in the native code's order (rectify.cpp, inverse3)."""
    c00 = a[1][1] * a[2][2] - a[1][2] * a[2][1]
    c01 = a[1][0] * a[2][2] - a[1][2] * a[2][0]
    c02 = a[1][0] * a[2][1] - a[1][1] * a[2][0]
    det = a[0][0] * c00 - a[0][1] * c01 + a[0][2] * c02
    if not (np.isfinite(det) and det != 0):
        raise ValueError("P @ R must be invertible")
    idet = 1.0 / det
    return [
        [
            c00 * idet,
            (a[0][2] * a[2][1] - a[0][1] * a[2][2]) * idet,
            (a[0][1] * a[1][2] - a[0][2] * a[1][1]) * idet,
        ],
        [
            -c01 * idet,
            (a[0][0] * a[2][2] - a[0][2] * a[2][0]) * idet,
            (a[0][2] * a[1][0] - a[0][0] * a[1][2]) * idet,
        ],
        [
            c02 * idet,
            (a[0][1] * a[2][0] - a[0][0] * a[2][1]) * idet,
            (a[0][0] * a[1][1] - a[0][1] * a[1][0]) * idet,
        ],
    ]


def remap(
    image: Any,
    map_x: Any,
    map_y: Any,
    *,
    out: np.ndarray | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Oracle of :func:`stereodepth.remap`: the rules of its docstring, in int64 for 8-bit
    images and float64 for 16-bit ones (``threads`` is checked, then unused)."""
    from .rectify import _as_image, _as_maps, _prepare_out

    img = _as_image("image", image)
    mx, my = _as_maps(map_x, map_y)
    check.threads(threads)
    result = _prepare_out(out, mx.shape + img.shape[2:], img.dtype, img)
    rows, cols = img.shape[:2]
    src = img.astype(np.int64 if img.dtype == np.uint8 else np.float64)
    if src.ndim == 2:
        src = src[:, :, None]

    def p(r: np.ndarray, c: np.ndarray) -> np.ndarray:
        inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
        v = src[np.clip(r, 0, rows - 1), np.clip(c, 0, cols - 1)]
        return np.where(inside[..., None], v, 0)

    def clamped(m: np.ndarray, hi: int) -> np.ndarray:
        c = np.where(np.isnan(m), np.float32(-2), m)
        return np.clip(c, np.float32(-2), np.float32(hi))

    cx, cy = clamped(mx, cols + 1), clamped(my, rows + 1)
    if img.dtype == np.uint8:  # fixed point, 1/1024 px
        big_x = np.rint(cx.astype(np.float64) * 1024).astype(np.int64)
        big_y = np.rint(cy.astype(np.float64) * 1024).astype(np.int64)
        ix, fx = big_x >> 10, (big_x & 1023)[..., None]
        iy, fy = big_y >> 10, (big_y & 1023)[..., None]
        top = p(iy, ix) * (1024 - fx) + p(iy, ix + 1) * fx
        bot = p(iy + 1, ix) * (1024 - fx) + p(iy + 1, ix + 1) * fx
        val = (top * (1024 - fy) + bot * fy + (1 << 19)) >> 20
    else:  # float64 at the map's own positions
        x = cx.astype(np.float64)
        y = cy.astype(np.float64)
        x0, y0 = np.floor(x), np.floor(y)
        fxf, fyf = (x - x0)[..., None], (y - y0)[..., None]
        ix, iy = x0.astype(np.int64), y0.astype(np.int64)
        top = p(iy, ix) * (1.0 - fxf) + p(iy, ix + 1) * fxf
        bot = p(iy + 1, ix) * (1.0 - fxf) + p(iy + 1, ix + 1) * fxf
        val = np.minimum(np.rint(top * (1.0 - fyf) + bot * fyf), 65535.0)
    result[...] = val.reshape(result.shape).astype(img.dtype)
    return result
