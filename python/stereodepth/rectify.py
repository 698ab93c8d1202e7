"""Raw stereo pairs to rectified pairs, natively: rectifying transforms, maps and remap.

A calibrated rig (intrinsics K1, K2, lens distortion D1, D2, and the pose R, T of the second
camera relative to the first) is rectified in three steps, each of which OpenCV users know:

1. :func:`stereo_rectify`: the rotations R1, R2 that make the image planes coplanar with
   horizontal (or vertical) epipolar lines, the new projections P1, P2 and the reprojection
   matrix Q: Bouguet's method, computed as ``cv2.stereoRectify`` does (OpenCV 5.0).
2. :func:`init_undistort_rectify_map`: per rectified pixel, where to sample the raw image
   (``cv2.initUndistortRectifyMap`` with float32 maps).
3. :func:`remap`: bilinear sampling through the maps, natively and threaded, in exactly
   specified arithmetic (``stereodepth.reference.remap`` is its oracle).

:class:`StereoRectifier` does all three once and then rectifies frame after frame.

Conventions are OpenCV's. Pixel (0, 0) is the centre of the top-left pixel. ``R`` and ``T``
map a point from the first (left) camera's frame to the second's: ``x2 = R @ x1 + T``, as
``cv2.stereoCalibrate`` returns them; ``T`` is in metres here, so the baseline and depths are
in metres. Distortion models:

- ``"none"``: the pinhole model;
- ``"plumb_bob"`` (ROS's name; Kalibr's ``radtan``): Brown-Conrady, coefficients in OpenCV's
  order ``k1 k2 p1 p2 [k3 [k4 k5 k6]]`` (4, 5 or 8 of them; the 8-coefficient form is
  OpenCV's rational model; OpenCV's 12 and 14 coefficient forms are taken when their thin
  prism and tilt terms are 0);
- ``"equidistant"`` (OpenCV's ``fisheye``): Kannala-Brandt, ``k1 k2 k3 k4``.

Sources: J.-Y. Bouguet, Camera Calibration Toolbox for Matlab (``rect.m``); OpenCV's
``stereoRectify``, ``undistortPoints`` and ``initUndistortRectifyMap`` (calib3d, OpenCV 5.0);
D. C. Brown, "Decentering distortion of lenses", Photogrammetric Engineering 32(3), 1966;
J. Kannala and S. S. Brandt, "A generic camera model and calibration method for conventional,
wide-angle, and fish-eye lenses", IEEE PAMI 28(8), 2006.
"""

from __future__ import annotations

import math
import os
from typing import Any, NamedTuple

import numpy as np

from . import _core
from . import _validate as check
from ._remap import _as_image, _precision, _prepare_out, remap
from .pointcloud import _as_q
from .rig import StereoRig

__all__ = [
    "DISTORTION_MODELS",
    "Rectification",
    "StereoRectifier",
    "init_undistort_rectify_map",
    "remap",
    "stereo_rectify",
]

#: The lens models the rectifier understands (see the module docstring).
DISTORTION_MODELS = ("none", "plumb_bob", "equidistant")

_COEFFICIENTS = {"none": (0,), "plumb_bob": (4, 5, 8), "equidistant": (4,)}


class Rectification(NamedTuple):
    """What :func:`stereo_rectify` returns, in ``cv2.stereoRectify``'s order.

    ``R1``, ``R2``: (3, 3) float64 rotations from each raw camera frame to its rectified frame.
    ``P1``, ``P2``: (3, 4) float64 projections of the rectified cameras, in the first
    rectified frame; ``P2[0, 3] = Tx * f`` (or ``P2[1, 3]`` for a vertical rig), metres x px.
    ``Q``: (4, 4) float64 disparity-to-depth matrix for :func:`stereodepth.reproject`.
    ``roi1``, ``roi2``: ``(x, y, width, height)`` of the rectified pixels whose source is
    inside the raw image (on OpenCV's 9 x 9 grid estimate; may differ from OpenCV's by 1 px
    where an edge falls exactly on a pixel boundary).
    """

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    roi1: tuple[int, int, int, int]
    roi2: tuple[int, int, int, int]


# --- argument checks ---------------------------------------------------------------------------
def _real_matrix(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A finite float64 array of `shape` (a (3,) also accepts (3, 1) and (1, 3))."""
    if value is None:
        raise TypeError(f"{name} must be a real array of shape {shape}, got None")
    arr = check.real_array(name, value)
    if len(shape) == 1 and arr.ndim == 2 and 1 in arr.shape:
        arr = arr.reshape(-1)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return np.ascontiguousarray(arr, dtype=np.float64)


def _projection(name: str, value: Any) -> np.ndarray:
    """A calibration's stored (3, 4) projection of a rectified camera: finite, with fx and fy
    > 0. StereoCalibration checks this itself; another object with its fields, which
    from_calibration takes, could hold a P of zeros (an uncalibrated camera's camera_info):
    P2's gave ZeroDivisionError from Q, P1's a rectifier of garbage maps."""
    P = _real_matrix(name, value, (3, 4))
    if not (P[0, 0] > 0 and P[1, 1] > 0):
        raise ValueError(
            f"{name} must be a projection of a rectified camera, [[fx, 0, cx, fx Tx], "
            f"[0, fy, cy, fy Ty], [0, 0, 1, 0]] with fx = P[0, 0] > 0 and fy = P[1, 1] > 0, "
            f"got {P.tolist()}"
        )
    return P


def _camera_matrix(name: str, value: Any) -> np.ndarray:
    K = _real_matrix(name, value, (3, 3))
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(
            f"{name} must have fx = {name}[0, 0] > 0 and fy = {name}[1, 1] > 0, "
            f"got {float(K[0, 0])!r} and {float(K[1, 1])!r}"
        )
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError(
            f"{name} must have the form [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), "
            f"got {K.tolist()}"
        )
    return K


def _model(name: str, value: Any) -> str:
    if not isinstance(value, str):
        raise TypeError(f"{name} must be a str, got {type(value).__name__} {value!r}")
    if value not in DISTORTION_MODELS:
        raise ValueError(f"{name} must be one of {DISTORTION_MODELS}, got {value!r}")
    return value


# The refusal of an OpenCV 12 or 14 coefficient distortion with thin prism or tilt terms
# (_rational_as_8), after the parameter's name.
_RATIONAL_TERMS = (
    "has thin prism or tilt terms (coefficients 9 to {size}), which the plumb_bob model does "
    "not take"
)


def _rational_as_8(d: np.ndarray) -> np.ndarray | None:
    """OpenCV's 12 and 14 coefficient forms of its rational model (thin prism, tilt; as
    cv2.stereoCalibrate returns them with CALIB_RATIONAL_MODEL: (1, 14), zeros after the
    8th) as their first 8 when the added terms are 0, None when they are not; any other count
    unchanged. The one rule of the rectifier and of the calibration readers."""
    if d.size not in (12, 14):
        return d
    return None if np.any(d[8:] != 0) else d[:8]


def _distortion(name: str, value: Any, model: str) -> np.ndarray:
    if value is None:
        arr = np.zeros(0)
    else:
        arr = check.real_array(name, value)
        if arr.ndim == 2 and 1 in arr.shape:
            arr = arr.reshape(-1)
        if arr.ndim != 1:
            raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if model == "plumb_bob" and arr.size in (12, 14):
        # Taken when the thin prism and tilt terms are 0, as the calibration readers take
        # them (refused before).
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite, got {arr.tolist()}")
        eight = _rational_as_8(arr)
        if eight is None:
            raise ValueError(f"{name} {_RATIONAL_TERMS.format(size=arr.size)}, got {arr.tolist()}")
        arr = eight
    if model == "none" and arr.size and np.any(arr != 0):
        raise ValueError(f"{name} must be empty or zero for distortion_model 'none', got {arr}")
    if model == "none":
        arr = np.zeros(0)
    elif model == "plumb_bob" and arr.size == 0:  # OpenCV's empty D: no distortion
        arr = np.zeros(4)
    allowed = _COEFFICIENTS[model]
    if arr.size not in allowed:
        raise ValueError(
            f"{name} must have {' or '.join(map(str, allowed))} coefficients for "
            f"distortion_model {model!r}, got {arr.size}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return np.ascontiguousarray(arr, dtype=np.float64)


def _size(name: str, value: Any) -> tuple[int, int]:
    """(width, height), both integers >= 1."""
    if not isinstance(value, (tuple, list, np.ndarray)) or len(value) != 2:
        raise TypeError(f"{name} must be a (width, height) pair of integers, got {value!r}")
    w = check.integer(f"{name}[0] (width)", value[0], minimum=1)
    h = check.integer(f"{name}[1] (height)", value[1], minimum=1)
    if w > 32000 or h > 32000:
        raise ValueError(f"{name} must be at most 32000 x 32000 pixels, got {(w, h)}")
    return w, h


#: How far from orthonormal R may be in :func:`stereo_rectify`: as the calibration readers'
#: ``ROTATION_TOLERANCE``, what a rotation printed to 6 significant digits keeps.
_ROUNDED_ROTATION = 1e-5


def _rotation(name: str, value: Any, tolerance: float = 1e-6) -> np.ndarray:
    R = _real_matrix(name, value, (3, 3))
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if err > tolerance or det <= 0 or abs(det - 1.0) > tolerance:
        raise ValueError(
            f"{name} must be a rotation matrix (orthonormal within {tolerance:g}, determinant "
            f"+1), got {R.tolist()} (max |R R^T - I| = {err:.3g}, det = {det:.9g})"
        )
    return R


def _nearest_rotation(R: np.ndarray) -> np.ndarray:
    """R itself when orthonormal to 1e-12, else U V^T of its SVD: what cv2.stereoRectify makes
    of a rounded R (its Rodrigues conversion)."""
    if float(np.abs(R @ R.T - np.eye(3)).max()) <= 1e-12:
        return R
    u, _, vt = np.linalg.svd(R)
    return np.ascontiguousarray(u @ vt)


def _zero_disparity(value: Any) -> bool:
    """A bool or numpy bool (numpy's was refused as "must be a bool, got bool"); TypeError
    naming ``zero_disparity`` and the value otherwise."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"zero_disparity must be a bool, got {type(value).__name__} {value!r}")
    return bool(value)


def _alpha(value: Any) -> float:
    a = check.finite("alpha", value)
    if a > 1 or (a < 0 and a != -1):
        raise ValueError(f"alpha must be -1 (OpenCV's default scaling) or in [0, 1], got {value!r}")
    return a


# --- the three steps -----------------------------------------------------------------------------
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
) -> Rectification:
    """The rectifying transforms of a calibrated stereo rig (Bouguet's method).

    Parameters
    ----------
    K1, K2
        (3, 3) camera matrices in pixels, ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
    D1, D2
        Distortion coefficients of ``distortion_model`` (see the module docstring); None or
        empty for ``"none"``.
    image_size
        ``(width, height)`` of the raw images in pixels.
    R, T
        (3, 3) rotation and (3,) translation from the first camera's frame to the second's
        (``x2 = R @ x1 + T``), as ``cv2.stereoCalibrate``; T in metres. An R rounded in print
        (orthonormal within 1e-5, as 6 significant digits leave it) is replaced by the
        nearest rotation, as ``cv2.stereoRectify`` does. The rig is horizontal
        when the rotated baseline's x component is the larger, else vertical; a T whose z
        component is the largest (one camera behind the other) is refused.
    alpha
        -1: OpenCV's default scaling; 0: zoom so every rectified pixel is valid; 1: keep every
        raw pixel (black borders); in between, a blend of the two scales.
    new_image_size
        ``(width, height)`` of the rectified images; None for ``image_size``.
    zero_disparity
        Give both rectified cameras the same principal point (OpenCV's
        ``CALIB_ZERO_DISPARITY``), so points at infinity have disparity 0. When False, only
        the coordinate across the baseline is shared.
    distortion_model
        ``"none"``, ``"plumb_bob"`` or ``"equidistant"`` for both cameras. Equidistant
        (fisheye) rigs are rectified as ``cv2.fisheye.stereoRectify`` does: the same rotations
        (always a horizontal rig), then the focal length and principal points from the
        undistorted midpoints of the image sides, chosen by ``balance`` and ``fov_scale``
        instead of ``alpha`` (which must stay -1); their ROIs are the whole image.
    balance
        Equidistant only, in [0, 1]: 0 the largest focal length (crop), 1 the smallest (keep
        the whole field of view).
    fov_scale
        Equidistant only, > 0: the focal length is divided by it.

    Returns
    -------
    Rectification
        ``(R1, R2, P1, P2, Q, roi1, roi2)``, equal to ``cv2.stereoRectify``'s (or
        ``cv2.fisheye.stereoRectify``'s) results to about 1e-12 relative (OpenCV 5.0),
        computed natively in Eigen; the ROIs within 1 pixel of OpenCV's (their edges are
        rounded, and an edge that falls on a pixel boundary to 1e-13 may round either way).
        This holds where the lens model is invertible over the image: where OpenCV's 5-step
        undistortion of the image border does not converge (strong distortion, a wide field
        of view, the rational model's k4..k6), the ``alpha > 0`` scaling depends on points
        that are off by pixels in both, and may differ from OpenCV's by pixels in P1, P2.

    Raises
    ------
    TypeError, ValueError
        Naming the parameter: wrong types, shapes or values, a K with skew, a wrong number of
        coefficients, an R that is not a rotation, a zero T.
    """
    args = _checked_rectify_args(
        K1, D1, K2, D2, image_size, R, T, alpha, new_image_size, zero_disparity,
        distortion_model, balance, fov_scale,
    )  # fmt: skip
    model, k1, d1, k2, d2, (width, height), rot, t, a, new_size, zd, b, fov = args
    new_w, new_h = (0, 0) if new_size is None else new_size
    if model == "equidistant":
        r = _core.fisheye_stereo_rectify(
            k1, d1, k2, d2, width, height, rot, t, b, fov, new_w, new_h, zd
        )
    else:
        r = _core.stereo_rectify(k1, d1, k2, d2, model, width, height, rot, t, a, new_w, new_h, zd)
    _check_finite_rectification(r, k1, k2, d1, d2, t, (width, height), a)
    return Rectification(
        r["R1"], r["R2"], r["P1"], r["P2"], r["Q"], tuple(r["roi1"]), tuple(r["roi2"])
    )


def _checked_rectify_args(
    K1: Any,
    D1: Any,
    K2: Any,
    D2: Any,
    image_size: Any,
    R: Any,
    T: Any,
    alpha: Any,
    new_image_size: Any,
    zero_disparity: Any,
    distortion_model: Any,
    balance: Any,
    fov_scale: Any,
) -> tuple[Any, ...]:
    """:func:`stereo_rectify`'s arguments checked, in its order: ``(model, K1, D1, K2, D2,
    (width, height), R, T, alpha, new_image_size or None, zero_disparity, balance,
    fov_scale)``, R the nearest rotation. Raises its TypeError or ValueError. Shared with the
    numpy oracle (:func:`stereodepth.reference.stereo_rectify`)."""
    model = _model("distortion_model", distortion_model)
    k1 = _camera_matrix("K1", K1)
    k2 = _camera_matrix("K2", K2)
    d1 = _distortion("D1", D1, model)
    d2 = _distortion("D2", D2, model)
    size = _size("image_size", image_size)
    rot = _nearest_rotation(_rotation("R", R, _ROUNDED_ROTATION))
    t = _real_matrix("T", T, (3,))
    if not np.sqrt(float(t @ t)) > 0:  # a length that underflows too, as the native check
        raise ValueError(f"T must not be zero: the cameras need a baseline, got {t.tolist()}")
    if abs(t[2]) >= max(abs(t[0]), abs(t[1])):
        # Bouguet's method turns the baseline into the new x (or y) axis: along the optical
        # axis, the rectified cameras would look sideways, away from what both images show.
        raise ValueError(
            "T must lie mostly across the optical axis (|T[0]| or |T[1]| the largest): the "
            f"cameras are one behind the other, which no rectification can pair, got {t.tolist()}"
        )
    a = _alpha(alpha)
    new_size = None if new_image_size is None else _size("new_image_size", new_image_size)
    zd = _zero_disparity(zero_disparity)
    b = check.finite("balance", balance)
    if not 0 <= b <= 1:
        raise ValueError(f"balance must be in [0, 1], got {balance!r}")
    fov = check.positive("fov_scale", fov_scale)
    if model == "equidistant":
        if a != -1:
            raise ValueError(
                "alpha applies to pinhole models; equidistant rigs take balance and fov_scale, "
                f"got alpha={alpha!r}"
            )
    elif b != 0.0 or fov != 1.0:
        raise ValueError(
            "balance and fov_scale apply to equidistant rigs; use alpha, got "
            f"balance={balance!r}, fov_scale={fov_scale!r}"
        )
    return model, k1, d1, k2, d2, size, rot, t, a, new_size, zd, b, fov


def _check_finite_rectification(
    r: Any,
    k1: np.ndarray,
    k2: np.ndarray,
    d1: np.ndarray,
    d2: np.ndarray,
    t: np.ndarray,
    size: tuple[int, int] | None = None,
    alpha: float = -1.0,
) -> None:
    """ValueError naming the inputs when R1, R2, P1, P2 or Q (``r[name]``) is not finite:
    focal lengths near 0 or 1e300, or distortion of 1e10, overflow Bouguet's method (said
    here, not later as "P must be finite" from the maps). With ``alpha >= 0`` and the raw
    image ``size``, a principal point on or beyond the image's border pixels (a K written
    without cx, cy: the 0 / 0 of the alpha scaling) is named. Shared with the numpy oracle."""
    for key in ("R1", "R2", "P1", "P2", "Q"):
        if not np.all(np.isfinite(r[key])):
            hint = ""
            if size is not None and alpha >= 0:
                w, h = size
                outside = [
                    f"{name}'s ({float(k[0, 2])!r}, {float(k[1, 2])!r})"
                    for name, k in (("K1", k1), ("K2", k2))
                    if not (0 < k[0, 2] < w - 1 and 0 < k[1, 2] < h - 1)
                ]
                if outside:
                    hint = (
                        f"; alpha={alpha!r} scales to the image's edges from the principal "
                        f"point (cx, cy), which must lie inside the {w} x {h} image: "
                        f"{' and '.join(outside)} does not (a K written without cx, cy?)"
                    )
            raise ValueError(
                f"the calibration gives a non-finite rectification ({key} = "
                f"{np.asarray(r[key]).tolist()}): K1, K2, D1, D2, R and T must describe a real "
                f"camera pair, got fx = {float(k1[0, 0])!r}, {float(k2[0, 0])!r}, "
                f"D1 = {d1.tolist()}, D2 = {d2.tolist()}, T = {t.tolist()}{hint}"
            )


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
    """The maps from a rectified image back to its raw image.

    For each pixel (column u, row v) of the ``size = (width, height)`` rectified image: the
    ray ``(P[:, :3] @ R)^-1 @ (u, v, 1)`` is projected through ``K`` and the distortion
    ``D`` of ``model``, giving the raw position to sample. ``R`` is the rectifying rotation
    (R1 or R2, or None for the identity), ``P`` the new (3, 3) camera matrix or the (3, 4)
    projection (P1 or P2). As ``cv2.initUndistortRectifyMap`` (``cv2.fisheye.`` for
    ``"equidistant"``) with ``CV_32FC1`` maps: float64 per pixel, rounded once to float32 (in
    tests they equal OpenCV's bit for bit). ``R`` may be a rotation rounded in print
    (orthonormal within 1e-5, as a camera_info's rectification_matrix printed to 6
    significant digits): it is used as given, ``(P R)^-1`` inverted in full as OpenCV does.
    Behind the camera (equidistant only) the maps hold -1e6.

    Returns ``(map_x, map_y)``, two (height, width) float32 arrays of raw column and row.
    Rows are split over ``threads`` (None or 0: every core); the maps do not depend on it.
    Raises TypeError or ValueError naming the parameter.
    """
    m = _model("model", model)
    k = _camera_matrix("K", K)
    d = _distortion("D", D, m)
    rot = np.eye(3) if R is None else _rotation("R", R, _ROUNDED_ROTATION)
    p = _new_camera(P, rot)
    width, height = _size("size", size)
    nthreads = check.threads(threads)
    map_x = np.empty((height, width), np.float32)
    map_y = np.empty((height, width), np.float32)
    _core.init_undistort_rectify_map(k, d, m, rot, p, map_x, map_y, nthreads)
    return map_x, map_y


def _new_camera(P: Any, rot: np.ndarray) -> np.ndarray:
    """``P`` of :func:`init_undistort_rectify_map` as its finite (3, 3) camera matrix (the
    first three columns of a (3, 4) projection), with ``P @ R`` invertible, checked in the
    kernel's arithmetic (rectify.cpp, mul and inverse3), so that the refusal names the values
    (the kernel's said "P @ R must be invertible" alone). Shared with the numpy oracle."""
    p = check.real_array("P", P)
    if p.shape == (3, 4):
        p = p[:, :3]
    elif p.shape != (3, 3):
        raise ValueError(f"P must have shape (3, 3) or (3, 4), got {p.shape}")
    p = _real_matrix("P", p, (3, 3))
    a = [
        [
            float(p[i, 0]) * float(rot[0, j])
            + float(p[i, 1]) * float(rot[1, j])
            + float(p[i, 2]) * float(rot[2, j])
            for j in range(3)
        ]
        for i in range(3)
    ]
    c00 = a[1][1] * a[2][2] - a[1][2] * a[2][1]
    c01 = a[1][0] * a[2][2] - a[1][2] * a[2][0]
    c02 = a[1][0] * a[2][1] - a[1][1] * a[2][0]
    det = a[0][0] * c00 - a[0][1] * c01 + a[0][2] * c02
    if not (math.isfinite(det) and det != 0):
        raise ValueError(
            f"P @ R must be invertible (its determinant is {det!r}; P's first three columns "
            f"are the new camera matrix), got P = {p.tolist()} and R = {rot.tolist()}"
        )
    return p


# --- the reusable rectifier ----------------------------------------------------------------------
def _rect_tuple(value: Any) -> tuple[int, int, int, int]:
    x, y, w, h = (int(v) for v in value)
    return (x, y, w, h)


class StereoRectifier:
    """Rectifies raw stereo pairs, frame after frame: transforms and maps built once.

    Build it with :meth:`from_calibration` (a :class:`stereodepth.calib.StereoCalibration`),
    :meth:`from_file` (any calibration file :func:`stereodepth.calib.read_stereo_calibration`
    reads) or the constructor (arrays). Then :meth:`rectify` each pair.

    Attributes: ``R1``, ``R2`` (3, 3), ``P1``, ``P2`` (3, 4), ``Q`` (4, 4) as
    :func:`stereo_rectify`; ``roi1``, ``roi2`` (the whole image when a calibration's own
    transforms are used); ``image_size`` (raw) and ``output_size`` (rectified), both
    ``(width, height)``; ``vertical`` (the baseline is along y: our matchers search along x,
    so such pairs need transposing before matching); :attr:`rig`.

    The rectified images are those of the rectified cameras P1, P2: depth computed from their
    disparity (with :attr:`rig` or :attr:`Q`) is in the rectified left camera's frame, which
    is the raw left camera's frame rotated by R1 (``x_rect = R1 @ x_raw``).

    A rectifier pickles (for a process pool or a Dask worker) without its remap tables, which
    the copy builds again on first use.
    """

    def __init__(
        self,
        *,
        K1: Any,
        D1: Any,
        K2: Any,
        D2: Any,
        R: Any,
        T: Any,
        image_size: tuple[int, int],
        distortion_model: str = "plumb_bob",
        alpha: float = -1.0,
        new_image_size: tuple[int, int] | None = None,
        zero_disparity: bool = True,
        balance: float = 0.0,
        fov_scale: float = 1.0,
        threads: int | None = None,
    ) -> None:
        """Computes the transforms with :func:`stereo_rectify` (same parameters; T in
        metres) and builds both maps; ``threads`` (None or 0: every core) is used for the maps
        and for every :meth:`rectify`."""
        r = stereo_rectify(
            K1,
            D1,
            K2,
            D2,
            image_size,
            R,
            T,
            alpha=alpha,
            new_image_size=new_image_size,
            zero_disparity=zero_disparity,
            distortion_model=distortion_model,
            balance=balance,
            fov_scale=fov_scale,
        )
        self._setup(
            K1=_camera_matrix("K1", K1),
            D1=_distortion("D1", D1, distortion_model),
            K2=_camera_matrix("K2", K2),
            D2=_distortion("D2", D2, distortion_model),
            model=distortion_model,
            image_size=_size("image_size", image_size),
            output_size=_size("image_size", image_size)
            if new_image_size is None
            else _size("new_image_size", new_image_size),
            rectification=r,
            threads=threads,
            T=_real_matrix("T", T, (3,)),
        )

    def _setup(
        self,
        *,
        K1: np.ndarray,
        D1: np.ndarray,
        K2: np.ndarray,
        D2: np.ndarray,
        model: str,
        image_size: tuple[int, int],
        output_size: tuple[int, int],
        rectification: Rectification | None,
        threads: int | None,
        T: np.ndarray | None,
    ) -> None:
        self._threads = check.threads(threads)
        self._T = T  # the translation received, for the message of rig
        self._image_size = image_size
        self._output_size = output_size
        self._model = model
        self._cameras = ((K1, D1), (K2, D2))
        if rectification is None:  # already rectified: nothing to resample
            self._R1 = np.eye(3)
            self._R2 = np.eye(3)
            self._P1 = np.hstack([K1, np.zeros((3, 1))])
            self._P2 = np.hstack([K2, np.zeros((3, 1))])
            self._Q = np.eye(4)
            self._roi1 = self._roi2 = (0, 0, *image_size)
            self._identity = True
            return
        self._identity = False
        self._R1, self._R2, self._P1, self._P2, self._Q, roi1, roi2 = rectification
        self._roi1, self._roi2 = _rect_tuple(roi1), _rect_tuple(roi2)
        self._tables: dict[str, tuple[Any, Any]] = {}
        self._table_pair("fixed")  # 8-bit images are the common case: build those now

    # Pickling (process pools, Dask workers) and deepcopy drop the native remap tables, which
    # are rebuilt from the maps on first use, like those of a new rectifier; copy.copy shares
    # them (they are read only), in a dict of its own.
    def __copy__(self) -> StereoRectifier:
        c = type(self).__new__(type(self))
        c.__dict__.update(self.__dict__)
        if not self._identity:
            c._tables = dict(self._tables)
        return c

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state.pop("_tables", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if not self._identity:
            self._tables = {}

    def _table_pair(self, precision: str) -> tuple[Any, Any]:
        """The left and right remap tables of a precision, built on first use."""
        pair = self._tables.get(precision)
        if pair is None:
            w, h = self._image_size
            tables = []
            for side in ("left", "right"):
                mx, my = self.maps(side)
                tables.append(_core.RemapTable(mx, my, h, w, precision, self._threads))
            pair = (tables[0], tables[1])
            self._tables[precision] = pair
        return pair

    # --- builders ------------------------------------------------------------------------------
    @classmethod
    def from_calibration(
        cls,
        calib: Any,
        *,
        alpha: float | None = None,
        new_image_size: tuple[int, int] | None = None,
        zero_disparity: bool | None = None,
        balance: float | None = None,
        fov_scale: float | None = None,
        threads: int | None = None,
    ) -> StereoRectifier:
        """A rectifier for a :class:`stereodepth.calib.StereoCalibration`.

        When the calibration holds rectifying transforms (R1, R2, P1, P2, as OpenCV's stereo
        YAML or ROS camera_info files do) and none of ``alpha``, ``balance``,
        ``new_image_size``, ``zero_disparity`` and ``fov_scale`` is given, those are used as
        they are; otherwise they are computed with :func:`stereo_rectify` (``alpha`` None
        means -1, ``balance`` None means 0, ``zero_disparity`` None means True, ``fov_scale``
        None means 1; ``balance`` and ``fov_scale`` for equidistant calibrations only). A
        calibration of images
        that are already rectified (``calib.rectified``: Middlebury, KITTI) gives a rectifier
        whose :meth:`rectify` returns its inputs unchanged. Raises TypeError or ValueError naming
        the field at fault.
        """
        for field in ("K1", "D1", "K2", "D2", "R", "T", "image_size", "distortion_model"):
            if not hasattr(calib, field):
                raise TypeError(
                    f"calib must be a StereoCalibration (missing {field!r}), got "
                    f"{type(calib).__name__}"
                )
        model = _model("calib.distortion_model", calib.distortion_model)
        K1 = _camera_matrix("calib.K1", calib.K1)
        K2 = _camera_matrix("calib.K2", calib.K2)
        D1 = _distortion("calib.D1", calib.D1, model)
        D2 = _distortion("calib.D2", calib.D2, model)
        size = _size("calib.image_size", tuple(calib.image_size))
        out_size = size if new_image_size is None else _size("new_image_size", new_image_size)
        self = cls.__new__(cls)
        if getattr(calib, "rectified", False):
            if new_image_size is not None and out_size != size:
                raise ValueError(
                    "new_image_size cannot differ from the image size for an already "
                    f"rectified calibration, got {out_size} and {size}"
                )
            self._setup(
                K1=K1,
                D1=D1,
                K2=K2,
                D2=D2,
                model=model,
                image_size=size,
                output_size=size,
                rectification=None,
                threads=threads,
                T=_received_t(calib.T),
            )
            self._from_rectified(calib)
            return self
        stored = [getattr(calib, f, None) for f in ("R1", "R2", "P1", "P2")]
        # Any rectification option given asks for a rectification computed with it: the
        # stored one was kept for zero_disparity=False and fov_scale=2 without a word.
        asked = any(
            v is not None for v in (alpha, balance, new_image_size, zero_disparity, fov_scale)
        )
        if not asked and all(m is not None for m in stored):
            R1 = _rotation("calib.R1", stored[0])
            R2 = _rotation("calib.R2", stored[1])
            P1 = _projection("calib.P1", stored[2])
            P2 = _projection("calib.P2", stored[3])
            Q = getattr(calib, "Q", None)
            Qm = _q_from_projections(P1, P2) if Q is None else _as_q(Q, "calib.Q")
            full = (0, 0, *size)
            rect = Rectification(R1, R2, P1, P2, Qm, full, full)
        else:
            rect = stereo_rectify(
                K1,
                D1,
                K2,
                D2,
                size,
                calib.R,
                calib.T,
                alpha=-1.0 if alpha is None else alpha,
                new_image_size=new_image_size,
                zero_disparity=True if zero_disparity is None else zero_disparity,
                distortion_model=model,
                balance=0.0 if balance is None else balance,
                fov_scale=1.0 if fov_scale is None else fov_scale,
            )
        self._setup(
            K1=K1,
            D1=D1,
            K2=K2,
            D2=D2,
            model=model,
            image_size=size,
            output_size=out_size,
            rectification=rect,
            threads=threads,
            T=_received_t(calib.T),
        )
        return self

    def _from_rectified(self, calib: Any) -> None:
        """P1, P2 and Q of an already rectified pair: the calibration's where it has them,
        else the cameras with the second shifted along x by T."""
        t = _real_matrix("calib.T", calib.T, (3,))
        K1, K2 = self._cameras[0][0], self._cameras[1][0]
        P1, P2, Q = (getattr(calib, f, None) for f in ("P1", "P2", "Q"))
        self._P1 = np.hstack([K1, np.zeros((3, 1))]) if P1 is None else _projection("calib.P1", P1)
        self._P2 = (
            np.hstack([K2, (K2[0, 0] * t[0]) * np.eye(3)[:, :1]])
            if P2 is None
            else _projection("calib.P2", P2)
        )
        self._Q = _q_from_projections(self._P1, self._P2) if Q is None else _as_q(Q, "calib.Q")

    @classmethod
    def from_file(
        cls,
        path: str | os.PathLike[str],
        *,
        second_path: str | os.PathLike[str] | None = None,
        alpha: float | None = None,
        new_image_size: tuple[int, int] | None = None,
        zero_disparity: bool | None = None,
        balance: float | None = None,
        fov_scale: float | None = None,
        threads: int | None = None,
        **read_options: Any,
    ) -> StereoRectifier:
        """A rectifier from a calibration file: read with
        :func:`stereodepth.calib.read_stereo_calibration` (OpenCV YAML/XML/JSON, ROS camera_info,
        Kalibr camchain, Middlebury, KITTI; ``second_path`` for the right camera's file where
        the format splits them, ``read_options`` such as ``image_size`` or
        ``translation_unit`` go to the reader), then :meth:`from_calibration` with the
        rectification options. The reader raises FileNotFoundError and ValueError naming the
        file and key."""
        try:
            from .calib import read_stereo_calibration  # type: ignore[attr-defined,unused-ignore]
        except ImportError as exc:  # the readers live in stereodepth.calib
            raise ImportError(
                "StereoRectifier.from_file needs stereodepth.calib.read_stereo_calibration"
            ) from exc
        if second_path is not None:
            read_options["second_path"] = second_path
        calib = read_stereo_calibration(path, **read_options)
        return cls.from_calibration(
            calib,
            alpha=alpha,
            new_image_size=new_image_size,
            zero_disparity=zero_disparity,
            balance=balance,
            fov_scale=fov_scale,
            threads=threads,
        )

    # --- per frame ------------------------------------------------------------------------------
    def rectify(
        self,
        left: np.ndarray,
        right: np.ndarray,
        *,
        out_left: np.ndarray | None = None,
        out_right: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rectifies one raw pair: (H, W) uint8/uint16 or (H, W, 3) uint8 images of the
        calibration's ``image_size``. Returns two images of ``output_size`` and the input
        dtype (written into ``out_left``/``out_right`` when given), sampled as :func:`remap`
        does. For an already rectified calibration the inputs are returned as they are, or
        copied into ``out_left``/``out_right`` when given. Raises ValueError when an output
        overlaps either image or the other output."""
        imgs = []
        for name, im in (("left", left), ("right", right)):
            arr = _as_image(name, im)
            w, h = self._image_size
            if arr.shape[:2] != (h, w):
                raise ValueError(
                    f"{name} must have the calibration's size {w} x {h} (width x height), "
                    f"got shape {arr.shape}"
                )
            imgs.append(arr)
        if imgs[0].shape != imgs[1].shape or imgs[0].dtype != imgs[1].dtype:
            raise ValueError(
                "left and right must have the same shape and dtype, got "
                f"{imgs[0].shape} {imgs[0].dtype} and {imgs[1].shape} {imgs[1].dtype}"
            )
        w, h = self._output_size
        shape = (h, w, *imgs[0].shape[2:])
        outs = (
            _prepare_out(out_left, shape, imgs[0].dtype, imgs[0], "out_left"),
            _prepare_out(out_right, shape, imgs[1].dtype, imgs[1], "out_right"),
        )
        # The left is written before the right is read, and both into their own buffer: an
        # out_left over the right image, or one array for both outputs, gave a wrong image.
        for name, out, other, other_name in (
            ("out_left", out_left, imgs[1], "right"),
            ("out_right", out_right, imgs[0], "left"),
            ("out_right", out_right, outs[0], "out_left"),
        ):
            if out is not None and np.shares_memory(out, other):
                raise ValueError(f"{name} must not overlap {other_name}")
        if self._identity:  # nothing to resample: the inputs, or copies in the given outputs
            given = (out_left is not None, out_right is not None)
            if not any(given):
                return left, right
            for out, img, is_given in zip(outs, imgs, given, strict=True):
                if is_given:
                    np.copyto(out, img)
            return (
                outs[0] if given[0] else left,
                outs[1] if given[1] else right,
            )
        for table, img, out in zip(self._table_pair(_precision(imgs[0])), imgs, outs, strict=True):
            table.apply(img, out, self._threads)
        return outs

    def maps(self, side: str) -> tuple[np.ndarray, np.ndarray]:
        """The float32 ``(map_x, map_y)`` of ``side`` ("left" or "right"), recomputed with
        :func:`init_undistort_rectify_map` (the rectifier keeps only the remap tables: the
        fixed-point one for 8-bit images, built at once, and the float one for 16-bit images,
        built on the first 16-bit frame)."""
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        i = 0 if side == "left" else 1
        K, D = self._cameras[i]
        if self._identity:
            w, h = self._image_size
            gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
            return gx, gy
        Rk, Pk = (self._R1, self._P1) if i == 0 else (self._R2, self._P2)
        return init_undistort_rectify_map(
            K, D, Rk, Pk, self._output_size, self._model, threads=self._threads
        )

    # --- what it computed -----------------------------------------------------------------------
    @property
    def R1(self) -> np.ndarray:
        return self._R1

    @property
    def R2(self) -> np.ndarray:
        return self._R2

    @property
    def P1(self) -> np.ndarray:
        return self._P1

    @property
    def P2(self) -> np.ndarray:
        return self._P2

    @property
    def Q(self) -> np.ndarray:
        """(4, 4) float64 reprojection matrix: pass it to :func:`stereodepth.reproject`."""
        return self._Q

    @property
    def roi1(self) -> tuple[int, int, int, int]:
        return self._roi1

    @property
    def roi2(self) -> tuple[int, int, int, int]:
        return self._roi2

    @property
    def image_size(self) -> tuple[int, int]:
        return self._image_size

    @property
    def output_size(self) -> tuple[int, int]:
        return self._output_size

    @property
    def vertical(self) -> bool:
        """True when the rectified baseline is along y (P2[1, 3] != P1[1, 3], the x
        translations equal)."""
        return _baseline_axis(self._P1, self._P2) == 1

    @property
    def rig(self) -> StereoRig:
        """The rectified rig as a :class:`StereoRig`: ``focal_px = P1[0, 0]``, baseline
        ``(P1[i, 3] - P2[i, 3]) / P2[0, 0]`` (i = 0, or 1 for a vertical rig; P1[i, 3] is 0
        as OpenCV writes it, and KITTI-style projections that place both cameras in a third
        camera's frame give the same baseline) in millimetres (T was in metres),
        ``doffs_px = P2[0, 2] - P1[0, 2]`` (0 with zero_disparity), and the output size.

        Raises ValueError when the first camera is to the right of (or, for a vertical rig,
        below) the second in the rectified frame: its disparities would be negative. The
        message gives the T received and OpenCV's convention (``x2 = R @ x1 + T``: T is the
        first camera's origin in the second camera's frame, so ``T[0] < 0`` when the left camera
        is first, ``T[1] < 0`` when the upper one is), and both remedies: a T of the wrong sign
        (the likeliest cause, in a hand-written file) is negated; a calibration that names the
        cameras the other way (made so, or with the rig upside down, rolled 180 degrees, and
        its cameras named by their place in the world: each camera's frame is then turned, and
        the camera on the world's left has the other on its own left) is swapped completely:
        K1 with K2, D1 with D2, R by R.T and T by -R.T @ T (swapping K and D alone leaves R, T
        those of the same refused rig; an upside-down rig's outputs are then upside down, as
        its images: turned 180 degrees and calibrated again, they are upright). The images'
        order is not seen here: images given the other way round than a calibration's cameras
        match to almost nothing."""
        f = float(self._P1[0, 0])
        i = _baseline_axis(self._P1, self._P2)
        relative = float(self._P2[i, 3] - self._P1[i, 3])
        if relative > 0:
            side, first = ("right of", "left") if i == 0 else ("below", "upper")
            t = self._T
            if t is not None and t[i] > 0:
                raise ValueError(
                    f"the first camera is {side} the second: T = {_vector(t)} m, and OpenCV's "
                    f"x2 = R @ x1 + T gives T[{i}] < 0 when the {first} camera is first. If T's "
                    "sign is wrong, negate it; if the cameras are named the other way, swap "
                    f"K1/K2 and D1/D2 and replace R by R.T, T by -R.T @ T. Give the {first} "
                    "image first"
                )
            received = "" if t is None else f", T = {_vector(t)} m"
            raise ValueError(
                f"the first camera is {side} the second in the rectified frame (P2[{i}, 3] - "
                f"P1[{i}, 3] = {relative:g} > 0{received}): check the calibration's R and T "
                "(OpenCV's x2 = R @ x1 + T) and its P1, P2 if it holds them"
            )
        baseline_m = -relative / float(self._P2[0, 0])
        doffs = float(self._P2[i, 2] - self._P1[i, 2])
        w, h = self._output_size
        return StereoRig.from_pixels(
            baseline_mm=baseline_m * 1000.0, focal_px=f, width_px=w, height_px=h, doffs_px=doffs
        )

    @property
    def threads(self) -> int:
        return self._threads

    def __repr__(self) -> str:
        w, h = self._image_size
        ow, oh = self._output_size
        return (
            f"StereoRectifier({w}x{h} -> {ow}x{oh}, model={self._model!r}, "
            f"focal_px={float(self._P1[0, 0]):.6g}, resamples={not self._identity})"
        )


def _vector(t: np.ndarray) -> str:
    """A translation for a message: ``[0.17, 0, 0]``."""
    return "[" + ", ".join(f"{float(v) + 0.0:.6g}" for v in t) + "]"  # + 0.0: no "-0"


def _received_t(value: Any) -> np.ndarray | None:
    """A calibration's T for :attr:`StereoRectifier.rig`'s message only: a finite (3,)
    float64 array, None when it is not one (a rectifier built from the calibration's own P1,
    P2 does not otherwise read T, and must not be refused for it)."""
    try:
        t = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        return None
    return t if t.shape == (3,) and bool(np.all(np.isfinite(t))) else None


def _baseline_axis(P1: np.ndarray, P2: np.ndarray) -> int:
    """0 when the rectified pair's baseline is along x, 1 when along y: the row of the
    projections' translation column in which P2 differs from P1 (P1's is 0 as OpenCV and ROS
    write it; KITTI's projections put both cameras in a reference camera's frame)."""
    return 1 if P2[1, 3] != P1[1, 3] and P2[0, 3] == P1[0, 3] else 0


def _q_from_projections(P1: np.ndarray, P2: np.ndarray) -> np.ndarray:
    """OpenCV's Q from rectified projections P1, P2 (horizontal or vertical rig), in the first
    camera's frame: the baseline is P2's translation relative to P1's."""
    f = float(P1[0, 0])
    i = _baseline_axis(P1, P2)
    t = float(P2[i, 3] - P1[i, 3]) / float(P2[0, 0])
    if t == 0 or not math.isfinite(t):
        raise ValueError(
            f"P2 must hold the baseline in P2[{i}, 3] (relative to P1[{i}, 3]), got "
            f"P1 = {P1.tolist()}, P2 = {P2.tolist()}"
        )
    cx1, cy1, cx2, cy2 = (float(v) for v in (P1[0, 2], P1[1, 2], P2[0, 2], P2[1, 2]))
    return np.array(
        [
            [1.0, 0.0, 0.0, -cx1],
            [0.0, 1.0, 0.0, -cy1],
            [0.0, 0.0, 0.0, f],
            [0.0, 0.0, -1.0 / t, ((cx1 - cx2) if i == 0 else (cy1 - cy2)) / t],
        ]
    )
