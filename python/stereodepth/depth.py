"""Disparity maps to depth maps, natively: numpy in, numpy out."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from . import _core
from . import _validate as check

__all__ = ["FLOAT32_MAX", "disparity_to_depth", "from_opencv_disparity"]

#: The largest ``|min_disparity|`` accepted, in pixels: far beyond any image width, small
#: enough that the raw threshold stays an exact float.
MAX_ABS_MIN_DISPARITY = 1 << 24

#: The default upper depth limit: the largest finite float32, so infinite depth is invalid.
FLOAT32_MAX = float(np.finfo(np.float32).max)

_DISPARITY_DTYPES = (np.float16, np.float32, np.float64, np.int16, np.uint16)


class DepthOptions:
    """The checked, resolved options shared by the native kernel and the numpy oracle."""

    __slots__ = (
        "baseline_m",
        "doffs_px",
        "dtype",
        "focal_px",
        "invalid_below",
        "invalid_value",
        "max_depth_m",
        "min_depth_m",
        "scale",
    )

    def __init__(
        self,
        disparity: np.ndarray,
        *,
        focal_px: Any,
        baseline_m: Any,
        doffs_px: Any,
        scale: Any,
        dtype: Any,
        min_depth_m: Any,
        max_depth_m: Any,
        invalid_value: Any,
        min_disparity: Any = None,
        check_rig: bool = True,
    ) -> None:
        self.focal_px = check.positive("focal_px", focal_px)
        self.baseline_m = check.positive("baseline_m", baseline_m)
        self.doffs_px = check.finite("doffs_px", doffs_px)
        kind = disparity.dtype
        opencv_format = scale is None and kind == np.int16  # x16 fixed point
        if scale is None:
            if kind == np.uint16:
                raise ValueError(
                    "scale is required for uint16 disparity (KITTI stores disparity * 256: "
                    "pass scale=1/256), got None"
                )
            scale = 1.0 / 16.0 if kind == np.int16 else 1.0
        self.scale = check.positive("scale", scale)
        if dtype is None:  # numpy reads None as float64: the message said "got float64"
            raise TypeError("dtype must be numpy.float32 or numpy.uint16, got None")
        try:
            out_dtype = np.dtype(dtype)
        except TypeError as exc:
            raise TypeError(f"dtype must be numpy.float32 or numpy.uint16, got {dtype!r}") from exc
        if out_dtype not in (np.dtype(np.float32), np.dtype(np.uint16)):
            raise TypeError(f"dtype must be numpy.float32 or numpy.uint16, got {out_dtype}")
        self.dtype = out_dtype
        if check_rig:
            self._check_ranges(kind)
        self.min_depth_m = (
            0.0 if min_depth_m is None else check.non_negative("min_depth_m", min_depth_m)
        )
        if max_depth_m is None:
            self.max_depth_m = FLOAT32_MAX
        else:
            self.max_depth_m = check.positive("max_depth_m", max_depth_m)
            if self.max_depth_m < self.min_depth_m:
                raise ValueError(
                    f"max_depth_m must be >= min_depth_m ({self.min_depth_m!r}), "
                    f"got {max_depth_m!r}"
                )
            if self.dtype == np.float32:
                # Compared in float32, a max beyond its range was inf, and a depth that
                # overflowed float32 (inf) passed as inside the range: it is above any max.
                self.max_depth_m = min(self.max_depth_m, FLOAT32_MAX)
        if self.min_depth_m > FLOAT32_MAX and (max_depth_m is None or self.dtype == np.float32):
            # Every depth would be invalid; the kernel named the max_depth_m not given.
            which = "float32 depth" if self.dtype == np.float32 else "depth (default max_depth_m)"
            raise ValueError(
                f"min_depth_m must be at most the largest float32, {FLOAT32_MAX!r} m (no {which} "
                f"lies beyond it: every pixel would be invalid), got {min_depth_m!r}"
            )
        # Which raw values mean "no disparity". OpenCV's int16 output marks holes with
        # (min_disparity - 1) * 16: every raw value below min_disparity * 16 is a hole, and
        # the rest are disparities, negative ones included. KITTI's uint16 uses 0.
        md = None if min_disparity is None else check_min_disparity(min_disparity)
        if invalid_value is None:
            self.invalid_value: float | None = 0.0 if kind == np.uint16 else None
            if md is None and kind == np.int16:
                md = 0  # OpenCV's default minDisparity
        else:
            self.invalid_value = check.real("invalid_value", invalid_value)
        # The raw threshold: raw < min_disparity / scale is a hole (exact for int16 x16).
        self.invalid_below: float | None = None if md is None else md / self.scale
        if kind != np.float64:
            # Raw values that are not float64 are compared with these in float32 by the float32
            # depth kernel and reproject's invalid_value, in float64 by the uint16 depth kernel
            # and reproject's threshold: a float32 map with holes of float32(0.1) and
            # invalid_value=0.1 had them as holes in float32 depth and as 1000 m in uint16
            # depth. Rounded to float32 here, every path compares the same numbers.
            with np.errstate(over="ignore"):  # beyond float32: +-inf, as the kernels cast it
                if self.invalid_value is not None:
                    self.invalid_value = float(np.float32(self.invalid_value))
                if self.invalid_below is not None:
                    self.invalid_below = float(np.float32(self.invalid_below))
        if md is None:
            pass
        elif opencv_format:
            if not -2047 <= md <= 2047:
                # As from_opencv_disparity: beyond, OpenCV's holes or its least disparity
                # overflow int16 (at 2048 and at 3000 every pixel was a hole, silently).
                raise ValueError(
                    f"min_disparity must be in [-2047, 2047] for OpenCV's int16 x16 disparity "
                    f"(its invalid value (min_disparity - 1) * 16 and its least disparity "
                    f"min_disparity * 16 must fit in int16), got {md}"
                )
        elif kind in (np.int16, np.uint16) and self.invalid_below is not None:
            top = int(np.iinfo(kind).max)
            if self.invalid_below > top:
                raise ValueError(
                    f"min_disparity / scale must be at most {top}, {kind}'s largest value (every "
                    f"raw value below it is a hole: every pixel would be one), got min_disparity "
                    f"{md} with scale {self.scale!r}"
                )

    def _check_ranges(self, kind: np.dtype) -> None:
        """The rig's numbers must survive the arithmetic the kernel does: B*f a finite double
        > 0 (beyond, every depth was NaN or 0, silently), and, for float32 depth from
        non-float64 input (float32 arithmetic), B*f and scale in float32's normal range and
        doffs within float32 (beyond, they rounded to inf or 0: every pixel NaN)."""
        k = self.focal_px * self.baseline_m
        if not 0.0 < k < math.inf:
            raise ValueError(
                f"focal_px * baseline_m must be a finite double > 0, got focal_px="
                f"{self.focal_px!r} and baseline_m={self.baseline_m!r}, whose product is {k!r}"
            )
        if self.dtype != np.float32 or kind == np.float64:
            return
        f32 = np.finfo(np.float32)
        lo, hi = float(f32.tiny), float(f32.max)
        why = (
            f"(float32 depth from {kind} disparity is computed in float32 arithmetic; pass "
            "float64 disparity for float64 arithmetic)"
        )
        for name, value in (("focal_px * baseline_m", k), ("scale", self.scale)):
            if not lo <= value <= hi:
                raise ValueError(
                    f"{name} must be within float32's normal range [{lo:.4g}, {hi:.4g}] {why}, "
                    f"got {value!r}"
                )
        if abs(self.doffs_px) > hi:
            raise ValueError(
                f"doffs_px must be within float32's range (|doffs_px| <= {hi:.4g}) {why}, got "
                f"{self.doffs_px!r}"
            )


def check_min_disparity(value: Any) -> int:
    """``min_disparity`` as an int in +-MAX_ABS_MIN_DISPARITY (TypeError, ValueError)."""
    return check.integer(
        "min_disparity", value, minimum=-MAX_ABS_MIN_DISPARITY, maximum=MAX_ABS_MIN_DISPARITY
    )


def as_disparity(disparity: Any, name: str = "disparity") -> np.ndarray:
    """Checks dtype and shape; never copies a numpy array in the machine's byte order (one in
    the other byte order is converted)."""
    arr: np.ndarray = check.native_order(check.disparity_array(name, disparity))
    if arr.dtype not in _DISPARITY_DTYPES:
        raise TypeError(
            f"{name} must have dtype float16, float32, float64, int16 (OpenCV, x16) or uint16 "
            f"(KITTI, x256), got {arr.dtype}"
        )
    if arr.ndim not in (2, 3):
        raise ValueError(f"{name} must have shape (H, W) or (N, H, W), got {arr.shape}")
    return arr


def prepare_out(out: Any, disparity: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Allocates `out`, or checks a caller's array: not masked, shape, dtype, C order,
    writeable, overlap."""
    if out is None:
        return np.empty(disparity.shape, dtype=dtype)
    if not isinstance(out, np.ndarray):
        raise TypeError(f"out must be a numpy.ndarray, got {type(out).__name__}")
    # A masked out was written and returned with its mask: valid depths hidden as "--" (as
    # reproject's out, refused).
    check.not_masked("out", out)
    if out.dtype != dtype:
        raise TypeError(f"out must have dtype {dtype} (the dtype argument), got {out.dtype}")
    if out.shape != disparity.shape:
        raise ValueError(f"out must have the shape of disparity {disparity.shape}, got {out.shape}")
    if not out.flags.c_contiguous:
        raise TypeError("out must be C-contiguous")
    if not out.flags.writeable:
        raise ValueError("out must be writeable")
    same_layout = (
        out.__array_interface__["data"][0] == disparity.__array_interface__["data"][0]
        and out.itemsize == disparity.itemsize
        and out.strides == disparity.strides
    )
    if not same_layout and np.shares_memory(out, disparity):
        raise ValueError("out overlaps disparity; pass a separate array or the same array")
    return out


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
    """Converts disparity maps to depth maps: Z = focal_px * baseline_m / (d * scale + doffs_px).

    Parameters
    ----------
    disparity
        (H, W) or (N, H, W) array of float16, float32, float64, int16 or uint16, in either
        byte order. int16 is read as OpenCV's fixed point (``scale`` defaults to 1/16; raw
        values below ``min_disparity * 16`` are holes); uint16 needs ``scale`` (1/256 for
        KITTI) and 0 is a hole. Not a masked array (``numpy.ma``: TypeError, its mask would
        be ignored): NaN marks a hole.
    focal_px, baseline_m, doffs_px
        The rig: focal length in pixels, baseline in metres, and the difference of the two
        cameras' principal points in pixels (Middlebury's ``doffs``; 0 for most rigs).
    scale
        Disparity in pixels per raw unit. Default 1 for float input, 1/16 for int16.
    dtype
        ``numpy.float32``: metres with NaN where invalid. ``numpy.uint16``: millimetres, rounded
        half to even, 0 where invalid (the depth-camera / ROS format), and clamped to the
        valid values: 65535 for 65.535 m and farther, 1 for 1 mm and nearer (so that a valid
        depth never becomes 0).
    min_depth_m, max_depth_m
        Depths outside this range are invalid. By default only non-finite depths are; an
        infinite float32 depth (a disparity so near 0 that the depth overflows float32) is
        invalid whatever ``max_depth_m``.
    invalid_value
        A raw value that marks holes, replacing the per-dtype default above (for int16, the
        ``min_disparity`` rule then applies only when ``min_disparity`` is given too). For
        input other than float64 it is compared in float32 (``0.1`` marks the float32 value
        nearest 0.1), whatever ``dtype``; so is the ``min_disparity / scale`` threshold.
    min_disparity
        The smallest disparity the matcher searched, in pixels (OpenCV's ``minDisparity``):
        raw values below ``min_disparity / scale`` are holes. OpenCV's StereoBM and
        StereoSGBM write holes as ``(minDisparity - 1) * 16``, so for int16 input this must be
        the matcher's ``minDisparity``; it defaults to 0, OpenCV's default. With a principal
        point offset (``doffs_px > 0``) negative disparities are valid: pass the negative
        ``min_disparity`` the matcher used. Other dtypes have no lower limit unless it is
        given. Raises TypeError unless it is an integer, and ValueError for int16 in OpenCV's
        format (no ``scale``) outside [-2047, 2047], as :func:`from_opencv_disparity`, or for
        other integer input when ``min_disparity / scale`` exceeds the dtype's largest value
        (every pixel would be a hole).
    out
        A preallocated C-contiguous array of ``dtype`` and the input's shape to write into.
        It may be the input itself when the item sizes match (float32 in place). Not a
        masked array (TypeError: its mask would hide depths written under it).
    threads
        Threads to split the rows over; None or 0 for every core available.

    A pixel is invalid where its value is NaN or a hole, where ``d * scale + doffs_px <= 0``
    (zero disparity is infinitely far), or where its depth leaves the range. Float32 results
    are computed in float32 arithmetic (float64 for float64 input); uint16 in float64.
    ValueError when ``focal_px * baseline_m`` is not a finite double > 0, and, in float32
    arithmetic, when it or ``scale`` leaves float32's normal range or ``doffs_px`` float32's
    range (every pixel would be NaN); ValueError too when ``min_depth_m`` exceeds the
    largest float32 (3.4e38 m) for float32 depth or without ``max_depth_m`` (every pixel
    would be invalid).

    A C-contiguous input is never copied; an input whose rows are not contiguous is copied
    once. The GIL is released while the kernel runs.
    """
    arr = as_disparity(disparity)
    opts = DepthOptions(
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
    nthreads = check.threads(threads)
    result = prepare_out(out, arr, opts.dtype)
    if arr.size == 0:
        return result
    if (arr.shape[-1] > 1 and arr.strides[-1] != arr.itemsize) or any(
        stride % arr.itemsize for stride in arr.strides
    ):
        arr = np.ascontiguousarray(arr)
    _core.disparity_to_depth(
        arr,
        result,
        opts.focal_px,
        opts.baseline_m,
        opts.doffs_px,
        opts.scale,
        opts.min_depth_m,
        opts.max_depth_m,
        opts.invalid_value,
        opts.invalid_below,
        nthreads,
    )
    return result


def from_opencv_disparity(raw: Any, *, min_disparity: int = 0) -> np.ndarray:
    """OpenCV's StereoBM / StereoSGBM output as float32 disparity in pixels, NaN for holes.

    ``raw`` is the int16 map that ``compute`` returns (disparity x 16, 4 fractional bits);
    ``min_disparity`` is the matcher's ``minDisparity`` (default 0, OpenCV's default). OpenCV
    marks holes with ``(minDisparity - 1) * 16``: every raw value below ``min_disparity * 16``
    becomes NaN, every other value ``raw / 16`` (negative disparities included, as a
    negative ``minDisparity`` produces). The inverse of
    :func:`stereodepth.to_opencv_disparity` with the same ``min_disparity``.

    Raises TypeError unless ``raw`` is an int16 array (not a masked one) and
    ``min_disparity`` an integer, and ValueError for a ``raw`` whose shape is not (H, W) or
    (N, H, W) (as every disparity map here), or a ``min_disparity`` outside [-2047, 2047],
    which no OpenCV matcher can have (its holes, ``(minDisparity - 1) * 16``, or its least
    disparity, ``minDisparity * 16``, would not fit in int16; every pixel would be NaN).
    """
    arr: np.ndarray = check.native_order(check.disparity_array("raw", raw))
    if arr.dtype != np.int16:
        raise TypeError(f"raw must be OpenCV's int16 disparity (x16), got dtype {arr.dtype}")
    if arr.ndim not in (2, 3):  # a 0-d one failed inside numpy ("does not support item ...")
        raise ValueError(f"raw must have shape (H, W) or (N, H, W), got {arr.shape}")
    md = check_min_disparity(min_disparity)
    if not -2047 <= md <= 2047:  # as to_opencv_disparity
        raise ValueError(
            f"min_disparity must be in [-2047, 2047] (OpenCV's invalid value (min_disparity - 1)"
            f" * 16 and its least disparity min_disparity * 16 must fit in int16), got {md}"
        )
    out: np.ndarray = arr.astype(np.float32) * np.float32(1 / 16)  # exact: a power of two
    out[arr.astype(np.int32) < md * 16] = np.nan
    return out
