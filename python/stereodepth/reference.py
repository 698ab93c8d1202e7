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
from ._reference_semi_global import semi_global_match
from .depth import DepthOptions, as_disparity, prepare_out

__all__ = [
    "block_match",
    "disparity_to_depth",
    "init_undistort_rectify_map",
    "remap",
    "reproject",
    "semi_global_match",
    "stereo_rectify",
    "undistort_points",
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
            ok = (
                (den > 0)
                & (den < np.inf)  # an infinite disparity is no match
                & (z >= np.float32(o.min_depth_m))
                & (z <= np.float32(o.max_depth_m))
            )
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
                    & (den < np.inf)
                    & (zf >= np.float32(o.min_depth_m))
                    & (zf <= np.float32(o.max_depth_m))
                )
            else:
                ok = (den > 0) & (den < np.inf) & (z >= o.min_depth_m) & (z <= o.max_depth_m)
            if o.invalid_value is not None:
                ok &= d != o.invalid_value
            if o.invalid_below is not None:
                ok &= d >= o.invalid_below
            if o.dtype == np.float32:
                depth = np.where(ok, zf, np.float32(np.nan))
            else:
                # 65535 for 65.535 m and farther, 1 for 1 mm and nearer (0 is a hole).
                mm = np.clip(np.rint(np.where(ok, z, 0.0) * 1000.0), 1.0, 65535.0)
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
            with np.errstate(over="ignore"):  # beyond float32: +-inf, as the kernel's cast
                ok &= arr.astype(np.float32) != np.float32(o.invalid_value)
    if o.invalid_below is not None:
        ok &= raw >= o.invalid_below
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
    from .rectify import (
        _ROUNDED_ROTATION,
        _camera_matrix,
        _distortion,
        _model,
        _new_camera,
        _rotation,
        _size,
    )

    m = _model("model", model)
    k_mat = _camera_matrix("K", K)
    d = np.zeros(8)
    coeffs = _distortion("D", D, m)
    d[: coeffs.size] = coeffs
    rot = np.eye(3) if R is None else _rotation("R", R, _ROUNDED_ROTATION)
    p = _new_camera(P, rot)
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
        # rounded once to float32, as the kernel: beyond its range, +-inf without a warning
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
    from ._remap import _as_image, _as_maps, _prepare_out

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


def _rotation_vector(r: np.ndarray) -> np.ndarray:
    """cv2.Rodrigues, matrix to vector (made orthogonal first; under ~2e-5 rad: zero)."""
    u, _, vt = np.linalg.svd(r)
    m = u @ vt
    v = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    s = np.sqrt((v @ v) * 0.25)
    c = min(max((m[0, 0] + m[1, 1] + m[2, 2] - 1) * 0.5, -1.0), 1.0)
    theta = np.arccos(c)
    if s < 1e-5:
        if c > 0:
            return np.zeros(3)
        v = np.sqrt(np.maximum((np.diag(m) + 1) * 0.5, 0.0))
        v[1] *= -1.0 if m[0, 1] < 0 else 1.0
        v[2] *= -1.0 if m[0, 2] < 0 else 1.0
        if abs(v[0]) < abs(v[1]) and abs(v[0]) < abs(v[2]) and (m[1, 2] > 0) != (v[1] * v[2] > 0):
            v[2] = -v[2]
        return np.asarray(v * (theta / np.linalg.norm(v)), dtype=np.float64)
    return np.asarray(v * (theta / (2 * s)), dtype=np.float64)


def _rotation_matrix(v: np.ndarray) -> np.ndarray:
    """cv2.Rodrigues, vector to matrix."""
    theta = float(np.linalg.norm(v))
    if theta < np.finfo(np.float64).eps:
        return np.eye(3)
    x, y, z = v / theta
    rx = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.asarray(
        np.cos(theta) * np.eye(3)
        + (1 - np.cos(theta)) * np.outer([x, y, z], [x, y, z])
        + (np.sin(theta) * rx)
    )


def undistort_points(points: Any, K: Any, D: Any, model: str = "plumb_bob") -> np.ndarray:
    """Oracle of the native undistortion (cv2.undistortPoints: 5 fixed-point iterations;
    cv2.fisheye.undistortPoints: Newton on theta, at most 10 steps, to 1e-8): (N, 2) pixels
    to (N, 2) ideal normalized coordinates. ``K``, ``D`` and ``model`` as
    :func:`stereodepth.stereo_rectify` takes them (``D`` None: no distortion). Raises
    TypeError or ValueError naming the parameter, as :func:`stereo_rectify` does for them; for
    ``points`` not of shape (N, 2)."""
    from .rectify import _camera_matrix, _distortion, _model

    m = _model("model", model)
    K = _camera_matrix("K", K)
    d = _distortion("D", D, m)
    p = check.real_array("points", points)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"points must have shape (N, 2), got shape {p.shape}")
    k = np.zeros(8)
    k[: d.size] = d
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    out = np.empty_like(p)
    for n, (u, v) in enumerate(p):
        if m == "equidistant":
            x, y = (u - cx) / fx, (v - cy) / fy
            theta_d = min(max(-np.pi / 2, np.sqrt(x * x + y * y)), np.pi / 2)
            theta, scale, converged = theta_d, 0.0, False
            if abs(theta_d) > 1e-8:
                for _ in range(10):
                    t2 = theta * theta
                    t4 = t2 * t2
                    t6 = t4 * t2
                    t8 = t6 * t2
                    fix = (
                        theta * (1 + k[0] * t2 + k[1] * t4 + k[2] * t6 + k[3] * t8) - theta_d
                    ) / (1 + 3 * k[0] * t2 + 5 * k[1] * t4 + 7 * k[2] * t6 + 9 * k[3] * t8)
                    theta -= fix
                    if abs(fix) < 1e-8:
                        converged = True
                        break
                scale = np.tan(theta) / theta_d
            else:
                converged = True
            flipped = (theta_d < 0 < theta) or (theta < 0 < theta_d)
            if not converged or flipped:
                out[n] = -1e6
                continue
            out[n] = (x * scale, y * scale) if theta_d > 1e-8 else (x, y)
            continue
        x = x0 = (u - cx) * (1.0 / fx)
        y = y0 = (v - cy) * (1.0 / fy)
        if m == "plumb_bob":
            for _ in range(5):
                r2 = x * x + y * y
                icdist = (1 + ((k[7] * r2 + k[6]) * r2 + k[5]) * r2) / (
                    1 + ((k[4] * r2 + k[1]) * r2 + k[0]) * r2
                )
                if icdist < 0:
                    x, y = x0, y0
                    break
                dx = 2 * k[2] * x * y + k[3] * (r2 + 2 * x * x)
                dy = k[2] * (r2 + 2 * y * y) + 2 * k[3] * x * y
                x, y = (x0 - dx) * icdist, (y0 - dy) * icdist
        out[n] = (x, y)
    return out


def stereo_rectify(
    K1: Any,
    D1: Any,
    K2: Any,
    D2: Any,
    image_size: tuple[int, int],
    R: Any,
    T: Any,
    *,
    alpha: float = -1.0,
    new_image_size: tuple[int, int] | None = None,
    zero_disparity: bool = True,
    distortion_model: str = "plumb_bob",
    balance: float = 0.0,
    fov_scale: float = 1.0,
) -> Any:
    """Oracle of :func:`stereodepth.stereo_rectify`: Bouguet's method (cv2.stereoRectify) or,
    for ``"equidistant"``, cv2.fisheye.stereoRectify, written out in numpy step by step. Agrees
    with the native code to about 1e-12 relative (the SVD that makes R orthogonal and the sums'
    order differ in the last bits). Raises as the native function does, the non-finite
    results of extreme inputs included."""
    # Extreme inputs overflow on the way, as in the native code: the result is checked.
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _stereo_rectify(
            K1, D1, K2, D2, image_size, R, T, alpha=alpha, new_image_size=new_image_size,
            zero_disparity=zero_disparity, distortion_model=distortion_model, balance=balance,
            fov_scale=fov_scale,
        )  # fmt: skip


def _stereo_rectify(
    K1: Any,
    D1: Any,
    K2: Any,
    D2: Any,
    image_size: tuple[int, int],
    R: Any,
    T: Any,
    *,
    alpha: float,
    new_image_size: tuple[int, int] | None,
    zero_disparity: bool,
    distortion_model: str,
    balance: float,
    fov_scale: float,
) -> Any:
    from .rectify import Rectification, _check_finite_rectification, _checked_rectify_args

    args = _checked_rectify_args(
        K1, D1, K2, D2, image_size, R, T, alpha, new_image_size, zero_disparity,
        distortion_model, balance, fov_scale,
    )  # fmt: skip
    model, k1, d1, k2, d2, (w, h), rot, t_in, a, new_size, zero_disparity, balance, fov_scale = args
    nw, nh = (w, h) if new_size is None else new_size
    r_r = _rotation_matrix(_rotation_vector(rot) * -0.5)
    t = r_r @ t_in
    if model == "equidistant":
        idx = 0
        uu = np.array([1.0 if t[0] > 0 else -1.0, 0.0, 0.0])
    else:
        idx = 0 if abs(t[0]) > abs(t[1]) else 1
        uu = np.zeros(3)
        uu[idx] = 1.0 if t[idx] > 0 else -1.0
    ww = np.cross(t, uu)
    if np.linalg.norm(ww) > 0:
        ww *= np.arccos(abs(t[idx]) / np.linalg.norm(t)) / np.linalg.norm(ww)
    wr = _rotation_matrix(ww)
    r1, r2 = wr @ r_r.T, wr @ r_r
    t_idx = float((r2 @ t_in)[idx])
    f32 = np.float32

    if model == "equidistant":
        cams = []
        for k_mat, d, rk in ((k1, d1, r1), (k2, d2, r2)):
            pts = np.array([[w // 2, 0], [w, h // 2], [w // 2, h], [0, h // 2]], np.float64)
            n = undistort_points(pts, k_mat, d, "equidistant")
            ray = (rk @ np.c_[n, np.ones(4)].T).T
            q = ray[:, :2] / ray[:, 2:]
            cn = q.mean(axis=0)
            ar = k_mat[0, 0] / k_mat[1, 1]
            cn[1] *= ar
            q[:, 1] *= ar
            fs = [
                w * 0.5 / (cn[0] - q[:, 0].min()),
                w * 0.5 / (q[:, 0].max() - cn[0]),
                h * 0.5 * ar / (cn[1] - q[:, 1].min()),
                h * 0.5 * ar / (q[:, 1].max() - cn[1]),
            ]
            f = balance * min(fs) + (1.0 - balance) * max(fs)
            f *= 1.0 / fov_scale
            c = np.array([-cn[0] * f + w * 0.5, (-cn[1] * f + h * ar * 0.5) / ar])
            fy = f / ar
            if new_image_size is not None:
                fy *= nh / h
                c *= (nw / w, nh / h)
            cams.append((fy, c))
        fc = min(cams[0][0], cams[1][0])
        c1, c2 = cams[0][1].copy(), cams[1][1].copy()
        if zero_disparity:
            c1 = c2 = (c1 + c2) * 0.5
        else:
            c1[1] = c2[1] = (c1[1] + c2[1]) * 0.5
        p1 = np.array([[fc, 0, c1[0], 0], [0, fc, c1[1], 0], [0, 0, 1, 0]])
        p2 = np.array([[fc, 0, c2[0], t_idx * fc], [0, fc, c2[1], 0], [0, 0, 1, 0]])
        q_mat = np.array([[1, 0, 0, -c1[0]], [0, 1, 0, -c1[1]], [0, 0, 0, fc],
                          [0, 0, -1 / t_idx, (c1[0] - c2[0]) / t_idx]])  # fmt: skip
        full = (0, 0, nw, nh)
        found = {"R1": r1, "R2": r2, "P1": p1, "P2": p2, "Q": q_mat}
        _check_finite_rectification(found, k1, k2, d1, d2, t_in)
        return Rectification(r1, r2, p1, p2, q_mat, full, full)

    ratio = (nw / w / 2) if idx == 1 else (nh / h / 2)
    fc = (k1[idx ^ 1, idx ^ 1] + k2[idx ^ 1, idx ^ 1]) * ratio
    cc = []
    for k_mat, d, rk in ((k1, d1, r1), (k2, d2, r2)):
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], np.float32)
        n = undistort_points(corners.astype(np.float64), k_mat, d, model).astype(f32)
        ray = (rk @ np.c_[n.astype(np.float64), np.ones(4)].T).T
        proj = (ray[:, :2] * (1.0 / ray[:, 2:]) * fc).astype(f32).astype(np.float64)
        cc.append(np.array([(w - 1) / 2, (h - 1) / 2]) - proj.sum(axis=0) * 0.25)
    if zero_disparity:
        cc[0] = cc[1] = (cc[0] + cc[1]) * 0.5
    else:
        cc[0][idx ^ 1] = cc[1][idx ^ 1] = (cc[0][idx ^ 1] + cc[1][idx ^ 1]) * 0.5

    def rectangles(k_mat: np.ndarray, d: np.ndarray, rk: np.ndarray, c: np.ndarray) -> Any:
        grid = np.array([[x * (w - 1) / 8, y * (h - 1) / 8] for y in range(9) for x in range(9)])
        p = np.array([[fc, 0, c[0]], [0, fc, c[1]], [0, 0, 1]])
        n = undistort_points(grid, k_mat, d, model)
        ray = ((p @ rk) @ np.c_[n, np.ones(81)].T).T
        q = (ray[:, :2] * (1.0 / ray[:, 2:])).reshape(9, 9, 2)
        inner = (q[:, 0, 0].max(), q[0, :, 1].max(), q[:, 8, 0].min(), q[8, :, 1].min())
        outer = (q[..., 0].min(), q[..., 1].min(), q[..., 0].max(), q[..., 1].max())
        return inner, outer

    (i1, o1), (i2, o2) = (rectangles(k1, d1, r1, cc[0]), rectangles(k2, d2, r2, cc[1]))
    c1n = np.array([nw * cc[0][0] / w, nh * cc[0][1] / h])
    c2n = np.array([nw * cc[1][0] / w, nh * cc[1][1] / h])
    s = 1.0
    if a >= 0:

        def ratios(c: np.ndarray, c0: np.ndarray, r: tuple[float, ...]) -> list[float]:
            return [c[0] / (c0[0] - r[0]), c[1] / (c0[1] - r[1]),
                    (nw - 1 - c[0]) / (r[2] - c0[0]), (nh - 1 - c[1]) / (r[3] - c0[1])]  # fmt: skip

        s0 = max(ratios(c1n, cc[0], i1) + ratios(c2n, cc[1], i2))
        s1 = min(ratios(c1n, cc[0], o1) + ratios(c2n, cc[1], o2))
        s = s0 * (1 - a) + s1 * a
    base = t_idx * fc
    fc *= s
    p1 = np.array([[fc, 0, c1n[0], 0], [0, fc, c1n[1], 0], [0, 0, 1, 0]])
    p2 = np.array([[fc, 0, c2n[0], 0], [0, fc, c2n[1], 0], [0, 0, 1, 0]])
    p2[idx, 3] = base * s

    q_mat = np.array([[1, 0, 0, -c1n[0]], [0, 1, 0, -c1n[1]], [0, 0, 0, fc],
                      [0, 0, -1 / t_idx, (c1n[idx] - c2n[idx]) / t_idx]])  # fmt: skip
    found = {"R1": r1, "R2": r2, "P1": p1, "P2": p2, "Q": q_mat}
    _check_finite_rectification(found, k1, k2, d1, d2, t_in, (w, h), a)

    def roi(r: tuple[float, ...], c0: np.ndarray, c: np.ndarray) -> tuple[int, int, int, int]:
        x, y = int(np.ceil((r[0] - c0[0]) * s + c[0])), int(np.ceil((r[1] - c0[1]) * s + c[1]))
        x1 = min(x + int(np.floor((r[2] - r[0]) * s)), nw)
        y1 = min(y + int(np.floor((r[3] - r[1]) * s)), nh)
        x, y = max(x, 0), max(y, 0)
        return (x, y, x1 - x, y1 - y) if x1 > x and y1 > y else (0, 0, 0, 0)

    return Rectification(r1, r2, p1, p2, q_mat, roi(i1, cc[0], c1n), roi(i2, cc[1], c2n))
