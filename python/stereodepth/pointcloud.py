"""Point clouds: disparity maps to XYZ (natively) and coloured binary PLY files."""

from __future__ import annotations

import errno
import math
import os
from typing import Any

import numpy as np

from . import _core
from . import _validate as check
from .depth import DepthOptions, as_disparity

__all__ = ["q_matrix", "reproject", "write_ply"]


def q_matrix(
    *, focal_px: float, baseline_m: float, cx_px: float, cy_px: float, doffs_px: float = 0.0
) -> np.ndarray:
    """The 4x4 reprojection matrix of a rectified rig, in OpenCV's convention
    (``cv2.stereoRectify``'s Q), scaled by the baseline so that W = d + doffs_px exactly::

        [[B, 0, 0, -cx B],
         [0, B, 0, -cy B],
         [0, 0, 0,  f B ],
         [0, 0, 1,  doffs]]

    Then Z = f B / (d + doffs), X = (x - cx) B / (d + doffs), Y = (y - cy) B / (d + doffs), in
    metres. ``doffs_px`` is cx_right - cx_left (Middlebury's ``doffs``; 0 for most rigs).

    ValueError, naming the two parameters, when a product (``focal_px * baseline_m``,
    ``cx_px * baseline_m``, ``cy_px * baseline_m``) overflows a double, or when
    ``focal_px * baseline_m`` rounds to 0 (every Z would be 0)."""
    f = check.positive("focal_px", focal_px)
    b = check.positive("baseline_m", baseline_m)
    cx = check.finite("cx_px", cx_px)
    cy = check.finite("cy_px", cy_px)
    doffs = check.finite("doffs_px", doffs_px)
    for name, value in (("focal_px", f), ("cx_px", cx), ("cy_px", cy)):
        product = value * b
        if not math.isfinite(product) or (name == "focal_px" and product == 0.0):
            raise ValueError(
                f"{name} * baseline_m must be a finite double{' > 0' if name == 'focal_px' else ''}"
                f" (an entry of Q), got {name}={value!r} and baseline_m={b!r}, whose product is "
                f"{product!r}"
            )
    return np.array(
        [
            [b, 0.0, 0.0, -cx * b],
            [0.0, b, 0.0, -cy * b],
            [0.0, 0.0, 0.0, f * b],
            [0.0, 0.0, 1.0, doffs],
        ],
        dtype=np.float64,
    )


class ReprojectOptions:
    """The checked, resolved options shared by the native kernel and the numpy oracle."""

    __slots__ = ("Q", "invalid_below", "invalid_value", "max_depth_m", "min_depth_m", "scale")

    def __init__(
        self,
        disparity: np.ndarray,
        *,
        Q: Any,
        focal_px: Any,
        baseline_m: Any,
        cx_px: Any,
        cy_px: Any,
        doffs_px: Any,
        scale: Any,
        min_depth_m: Any,
        max_depth_m: Any,
        invalid_value: Any,
        min_disparity: Any = None,
    ) -> None:
        rig = {
            "focal_px": focal_px,
            "baseline_m": baseline_m,
            "cx_px": cx_px,
            "cy_px": cy_px,
            "doffs_px": doffs_px,
        }
        if Q is not None:
            given = [k for k, v in rig.items() if v is not None]
            if given:
                raise ValueError(
                    "give either Q or focal_px and baseline_m (with cx_px, cy_px, doffs_px), "
                    f"not both; got Q and {', '.join(given)}"
                )
            self.Q = _as_q(Q)
        else:
            if focal_px is None or baseline_m is None:
                missing = [k for k in ("focal_px", "baseline_m") if rig[k] is None]
                raise ValueError(
                    f"reproject needs Q, or focal_px and baseline_m; {' and '.join(missing)} "
                    "missing"
                )
            rows, cols = disparity.shape[-2:]
            self.Q = q_matrix(
                focal_px=focal_px,
                baseline_m=baseline_m,
                cx_px=(cols - 1) / 2.0 if cx_px is None else cx_px,
                cy_px=(rows - 1) / 2.0 if cy_px is None else cy_px,
                doffs_px=0.0 if doffs_px is None else doffs_px,
            )
        # The disparity conventions (scale, holes, limits) are exactly disparity_to_depth's;
        # the rig numbers given here only satisfy its checks and are not used.
        o = DepthOptions(
            disparity,
            focal_px=1.0,
            baseline_m=1.0,
            doffs_px=0.0,
            scale=scale,
            dtype=np.float32,
            min_depth_m=min_depth_m,
            max_depth_m=max_depth_m,
            invalid_value=invalid_value,
            min_disparity=min_disparity,
            check_rig=False,  # reproject computes in float64, with Q's numbers
        )
        self.scale = o.scale
        self.min_depth_m = o.min_depth_m
        self.max_depth_m = o.max_depth_m
        self.invalid_value = o.invalid_value
        self.invalid_below = o.invalid_below


def _as_q(Q: Any, name: str = "Q") -> np.ndarray:
    """Q as a float64 4x4 matrix: real (a complex one lost its imaginary part with only a
    ComplexWarning; a bool one was read as 0 and 1), finite and invertible. The messages
    name ``name`` (``calib.Q`` for a calibration's)."""
    try:
        raw = np.asarray(Q)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a 4x4 array of real numbers, got {Q!r}") from exc
    if raw.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be a 4x4 array of real numbers, got dtype {raw.dtype}")
    q = raw.astype(np.float64)
    if q.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 matrix, got shape {q.shape}")
    if not np.isfinite(q).all():
        raise ValueError(f"{name} must be finite, got {q.tolist()}")
    rank = int(np.linalg.matrix_rank(q))
    if rank < 4:
        # A singular Q maps every pixel onto a plane or a line (all zeros: W = 0, every point
        # invalid): no reprojection matrix is (cv2.stereoRectify's has rank 4).
        raise ValueError(f"{name} must be invertible (rank 4), got rank {rank}: {q.tolist()}")
    return q


def prepare_points_out(out: Any, disparity: np.ndarray) -> np.ndarray:
    """Allocates the (..., 3) float32 result, or checks a caller's array."""
    shape = (*disparity.shape, 3)
    if out is None:
        return np.empty(shape, dtype=np.float32)
    if not isinstance(out, np.ndarray):
        raise TypeError(f"out must be a numpy.ndarray, got {type(out).__name__}")
    check.not_masked("out", out)
    if out.dtype != np.float32:
        raise TypeError(f"out must have dtype float32, got {out.dtype}")
    if out.shape != shape:
        raise ValueError(f"out must have shape {shape}, got {out.shape}")
    if not out.flags.c_contiguous:
        raise TypeError("out must be C-contiguous")
    if not out.flags.writeable:
        raise ValueError("out must be writeable")
    if np.shares_memory(out, disparity):
        raise ValueError("out overlaps disparity; pass a separate array")
    return out


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
    """Disparity maps to 3-D points: (H, W) -> (H, W, 3) float32 X, Y, Z, NaN where invalid.

    Like ``cv2.reprojectImageTo3D``, but invalid pixels are NaN (all three coordinates)
    instead of a far-away sentinel, int16 input is read as OpenCV's x16 fixed point, and the
    rows are split over threads.

    Parameters
    ----------
    disparity
        (H, W) or (N, H, W) array of float16, float32, float64, int16 or uint16, with the
        conventions of :func:`stereodepth.disparity_to_depth` (``scale``, ``invalid_value``,
        ``min_disparity``): for OpenCV's int16 output pass the matcher's ``minDisparity`` as
        ``min_disparity`` (default 0), since raw values below ``min_disparity * 16`` are holes.
    Q
        OpenCV's 4x4 reprojection matrix (from ``cv2.stereoRectify``):
        [X Y Z W]^T = Q [x y d 1]^T. The points come out in the units of its translation.
        Real (int or float; TypeError for bool, complex or object), finite and invertible
        (ValueError otherwise: a singular Q flattens the scene onto a plane or a line).
        OpenCV's Q has ``Q[3, 2] = -1 / Tx`` with ``Tx < 0`` when the right camera is to the
        right of the left one; a Q of the other sign (the cameras swapped) puts every point
        of a positive disparity behind the camera, so every point is invalid (NaN).
    focal_px, baseline_m, cx_px, cy_px, doffs_px
        Instead of Q: the rectified rig (see :func:`q_matrix`); points in metres, the camera
        at the origin, x right, y down, z forward. ``cx_px`` and ``cy_px`` (the left
        camera's principal point) default to the image centre, ``(W - 1) / 2`` and
        ``(H - 1) / 2``; ``doffs_px`` to 0.
    min_depth_m, max_depth_m
        Points whose Z leaves this range are invalid (a Z that overflows float32 whatever
        ``max_depth_m``); ValueError for a ``min_depth_m`` beyond the largest float32,
        3.4e38 (every point would be invalid).
    out
        A preallocated C-contiguous float32 array of shape ``disparity.shape + (3,)``.
    threads
        Threads to split the rows over; None or 0 for every core available.

    A point is invalid where its disparity is NaN or a hole, where it is not in front of
    the camera (Z <= 0, which includes zero disparity: infinitely far), or where a coordinate
    is not finite. Computed in float64, rounded to float32 once; the GIL is released.
    """
    arr = as_disparity(disparity)
    opts = ReprojectOptions(
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
    nthreads = check.threads(threads)
    result = prepare_points_out(out, arr)
    if arr.size == 0:
        return result
    if arr.dtype == np.float16:
        arr = arr.astype(np.float32, order="C")  # exact; C order, as the kernel needs
    elif (arr.shape[-1] > 1 and arr.strides[-1] != arr.itemsize) or any(
        stride % arr.itemsize for stride in arr.strides
    ):
        arr = np.ascontiguousarray(arr)
    _core.reproject(
        arr,
        result,
        opts.Q,
        opts.scale,
        opts.min_depth_m,
        opts.max_depth_m,
        opts.invalid_value,
        opts.invalid_below,
        nthreads,
    )
    return result


# --- PLY --------------------------------------------------------------------------------------
_PLY_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
_PLY_VERTEX_RGB = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
)


def _colours_u8(colors: Any, n_points_shape: tuple[int, ...]) -> np.ndarray:
    """Colours as (..., 3) uint8: grey is repeated, uint16 keeps its high byte."""
    # In the machine's byte order: a big-endian uint16 image (a 16-bit PNG decoded by hand,
    # FITS) was refused as "got >u2".
    c: np.ndarray = check.native_order(check.array("colors", colors))
    if c.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"colors must have dtype uint8 or uint16, got {c.dtype}")
    if c.shape == n_points_shape:
        c = np.repeat(c[..., None], 3, axis=-1)
    if c.shape != (*n_points_shape, 3):
        raise ValueError(
            f"colors must have shape {n_points_shape} (grey) or {(*n_points_shape, 3)} (RGB) "
            f"to match points, got {c.shape}"
        )
    if c.dtype == np.uint16:
        c = (c >> 8).astype(np.uint8)
    return c


def write_ply(
    path: str | os.PathLike[str],
    points: Any,
    colors: Any = None,
    *,
    comment: str | None = None,
) -> int:
    """Writes the finite points as a binary little-endian PLY file, atomically.

    ``points`` is (N, 3) or (H, W, 3) (as :func:`reproject` returns) real; rows with a
    non-finite coordinate are left out. ``colors`` is optional: uint8 or uint16, RGB with
    the shape of ``points`` or grey without the last axis (the left image, for a point cloud
    from :func:`reproject`). Returns the number of points written.

    Vertex properties: float x, y, z, and uchar red, green, blue when coloured.

    Raises ValueError for a finite coordinate beyond float32's range (about 3.4e38), a ragged
    nested list as ``points`` or ``colors``, or a ``comment`` that is not ASCII, TypeError
    for a ``path`` that is not a str or os.PathLike or a ``comment`` that is not a str,
    FileNotFoundError (naming ``path``) when its folder does not exist, before any work, and
    OSError naming ``path`` when it cannot be written; ``path`` is then left as it was."""
    from .io import atomic_write

    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a str or os.PathLike, got {type(path).__name__} {path!r}")
    target = os.fspath(path)
    if not target:  # "" is not the current folder
        raise ValueError("path must not be empty, got ''")
    from .io import folder_fault

    fault = folder_fault(target)
    if fault is not None:
        missing = fault.startswith("the folder")  # else a file is in the way
        raise (FileNotFoundError if missing else NotADirectoryError)(
            errno.ENOENT if missing else errno.ENOTDIR,
            f"cannot write the PLY file: {fault}",
            target,
        )
    if os.path.isdir(target):
        raise IsADirectoryError(errno.EISDIR, "cannot write the PLY file over a folder", target)
    if comment is not None and not isinstance(comment, str):
        raise TypeError(f"comment must be a str, got {type(comment).__name__} {comment!r}")
    if comment is not None and not comment.isascii():
        raise ValueError(f"comment must be ASCII text (PLY headers are ASCII), got {comment!r}")
    pts = check.array("points", points)
    if pts.dtype.kind not in "iuf":
        raise TypeError(f"points must be a real array, got dtype {pts.dtype}")
    if pts.ndim < 2 or pts.shape[-1] != 3:
        raise ValueError(f"points must have shape (N, 3) or (H, W, 3), got {pts.shape}")
    cols = None if colors is None else _colours_u8(colors, pts.shape[:-1])
    flat = pts.reshape(-1, 3)
    if flat.dtype.kind == "f" and flat.dtype.itemsize > 4 and flat.size:
        finite = np.abs(flat[np.isfinite(flat)])
        if finite.size and finite.max() > np.finfo(np.float32).max:
            raise ValueError(
                "points must fit in float32 (PLY stores float x, y, z), got a finite "
                f"coordinate of magnitude {float(finite.max())!r}"
            )
    pts32 = flat.astype(np.float32, copy=False)
    keep = np.isfinite(pts32).all(axis=1)
    n = int(np.count_nonzero(keep))
    vertex = np.empty(n, dtype=_PLY_VERTEX if cols is None else _PLY_VERTEX_RGB)
    kept = pts32[keep]
    vertex["x"], vertex["y"], vertex["z"] = kept[:, 0], kept[:, 1], kept[:, 2]
    properties = ["property float x", "property float y", "property float z"]
    if cols is not None:
        c = cols.reshape(-1, 3)[keep]
        vertex["red"], vertex["green"], vertex["blue"] = c[:, 0], c[:, 1], c[:, 2]
        properties += ["property uchar red", "property uchar green", "property uchar blue"]
    header = ["ply", "format binary_little_endian 1.0"]
    if comment:
        header += [f"comment {line}" for line in comment.splitlines()]
    header += [f"element vertex {n}", *properties, "end_header"]
    try:
        with atomic_write(target) as f:
            f.write(("\n".join(header) + "\n").encode("ascii"))
            f.write(vertex.tobytes())
    except OSError as exc:
        if exc.filename == target:
            raise
        # The error names our temporary file: name the user's path instead.
        raise OSError(
            exc.errno, f"cannot write the PLY file: {exc.strerror or exc}", target
        ) from None
    return n
