"""Bilinear resampling of images through maps (``cv2.remap`` with ``INTER_LINEAR`` and a
constant 0 border), natively: exact fixed point for 8-bit images, float64 for 16-bit ones.

The rules are in :func:`remap`; ``cpp/include/stereodepth/remap.hpp`` holds the same, and
``stereodepth.reference.remap`` is the numpy oracle. The public name is
:func:`stereodepth.remap` (also ``stereodepth.rectify.remap``): this module is private so
that the name stays the function's. :class:`stereodepth.StereoRectifier` keeps the maps in
the kernels' form and calls the same kernel per frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _core
from . import _validate as check

__all__ = ["remap"]


def _array_arg(name: str, value: Any) -> np.ndarray:
    if not isinstance(value, np.ndarray):
        raise TypeError(f"{name} must be a numpy.ndarray, got {type(value).__name__}")
    check.not_masked(name, value)
    return value


def _as_image(name: str, value: Any) -> np.ndarray:
    arr = check.native_order(_array_arg(name, value))
    if arr.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"{name} must have dtype uint8 or uint16, got {arr.dtype}")
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3 and arr.dtype == np.uint8)):
        raise ValueError(
            f"{name} must be (H, W) uint8/uint16 or (H, W, 3) uint8, got shape {arr.shape} "
            f"{arr.dtype}"
        )
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{name} must have at least one row and column, got shape {arr.shape}")
    if arr.shape[0] > 32000 or arr.shape[1] > 32000:
        raise ValueError(f"{name} must be at most 32000 x 32000 pixels, got shape {arr.shape}")
    return np.ascontiguousarray(arr)


def _as_maps(map_x: Any, map_y: Any) -> tuple[np.ndarray, np.ndarray]:
    mx = check.native_order(_array_arg("map_x", map_x))
    my = check.native_order(_array_arg("map_y", map_y))
    for name, m in (("map_x", mx), ("map_y", my)):
        if m.dtype not in (np.float32, np.float64):
            raise TypeError(f"{name} must have dtype float32 (or float64), got {m.dtype}")
        if m.ndim != 2:
            raise ValueError(f"{name} must be 2-D, got shape {m.shape}")
    if mx.shape != my.shape:
        raise ValueError(f"map_x and map_y must have the same shape, got {mx.shape} and {my.shape}")
    # A float64 position beyond float32 (1e300 marking "no source") rounds to +-inf, which
    # the clamp puts outside the image, as the docstring says: no overflow warning for it.
    with np.errstate(over="ignore"):
        mx = np.ascontiguousarray(mx, dtype=np.float32)
        my = np.ascontiguousarray(my, dtype=np.float32)
    return mx, my


def _prepare_out(
    out: Any, shape: tuple[int, ...], dtype: np.dtype, image: np.ndarray, name: str = "out"
) -> np.ndarray:
    """A new output, or the caller's checked: dtype, shape, C order, writeable, no overlap
    with the image it is sampled from."""
    if out is None:
        return np.empty(shape, dtype)
    arr = _array_arg(name, out)
    if arr.dtype != dtype:
        raise TypeError(f"{name} must have dtype {dtype} (the image's), got {arr.dtype}")
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not arr.flags.c_contiguous:
        raise TypeError(f"{name} must be C-contiguous")
    if not arr.flags.writeable:
        raise ValueError(f"{name} must be writeable")
    if np.shares_memory(arr, image):
        raise ValueError(f"{name} must not overlap the image it is sampled from")
    return arr


def _precision(img: np.ndarray) -> str:
    """The remap table an image needs: "fixed" for 8-bit images, "float" for 16-bit ones."""
    return "float" if img.dtype == np.uint16 else "fixed"


def remap(
    image: np.ndarray,
    map_x: np.ndarray,
    map_y: np.ndarray,
    *,
    out: np.ndarray | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Bilinear resampling: ``out[v, u] = image(map_y[v, u], map_x[v, u])``.

    ``image``: (H, W) uint8 or uint16, or (H, W, 3) uint8 (channels interleaved, any order).
    ``map_x``, ``map_y``: (h, w) float32 raw column and row positions (float64 is rounded to
    float32 first; beyond float32's range, to +-inf). Returns (h, w[, 3]) of the image's
    dtype (into ``out`` when given).

    Exactly specified arithmetic. Each position is clamped to [-2, W + 1] x [-2, H + 1] (NaN
    to -2; no result changes) and ``p`` is the image, 0 outside it (``cv2.BORDER_CONSTANT``
    with value 0).

    8-bit images (grey and RGB), in integers: positions rounded half to even to 1/1024 px,
    ``X = rint(x * 1024)``, ``ix = X >> 10``, ``fx = X & 1023`` (likewise y), then::

        top = p[iy, ix] * (1024 - fx) + p[iy, ix + 1] * fx
        bot = p[iy + 1, ix] * (1024 - fx) + p[iy + 1, ix + 1] * fx
        out = (top * (1024 - fy) + bot * fy + 2**19) >> 20

    the bilinear value at the rounded position, rounded half up.

    16-bit images, in float64 (1/1024 px steps would move 16-bit values by up to 64 levels):
    ``ix = floor(x)``, ``fx = x - ix``, ``top = p[iy, ix] * (1 - fx) + p[iy, ix + 1] * fx``,
    ``bot`` likewise, ``out = rint(top * (1 - fy) + bot * fy)`` (half to even), one rounding
    per operation in this order.

    Either way the result is within 1 grey level of ``cv2.remap(..., cv2.INTER_LINEAR)``
    with float maps (OpenCV 5 interpolates those in float32) and identical for every thread
    count and instruction set; ``stereodepth.reference.remap`` is the numpy oracle. Images up
    to 32000 x 32000 px. The GIL is released while the kernel runs. Raises TypeError (dtypes,
    types) or ValueError (shapes) naming the parameter.
    """
    img = _as_image("image", image)
    mx, my = _as_maps(map_x, map_y)
    nthreads = check.threads(threads)
    result = _prepare_out(out, mx.shape + img.shape[2:], img.dtype, img)
    if mx.size == 0:
        return result
    table = _core.RemapTable(mx, my, img.shape[0], img.shape[1], _precision(img), nthreads)
    table.apply(img, result, nthreads)
    return result
