"""Argument checks shared by the public functions.

Every check raises TypeError for a wrong type and ValueError for a wrong value, with a message
that names the parameter, states the rule and shows what was received.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np


def native_order(arr: Any) -> Any:
    """A numpy (or dask) array in the machine's byte order: one in the other byte order (a
    big-endian map or image from ``np.load`` of a file written elsewhere, FITS, a PGM read by
    hand) is converted, a copy in that case only, so that the dtype checks see what the values
    are."""
    return arr if arr.dtype.isnative else arr.astype(arr.dtype.newbyteorder("="))


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def real(name: str, value: Any) -> float:
    """A real scalar (int or float, not bool) as float; may be NaN or infinite."""
    if not _is_real(value):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__} {value!r}")
    try:
        return float(value)
    except OverflowError:  # an int beyond a double: was Python's "int too large to convert"
        shown = str(value) if len(str(value)) <= 40 else f"an integer of {len(str(value))} digits"
        raise ValueError(
            f"{name} must be within the range of a double (about 1.8e308), got {shown}"
        ) from None


def finite(name: str, value: Any) -> float:
    v = real(name, value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


def positive(name: str, value: Any) -> float:
    """A finite real > 0."""
    v = real(name, value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def non_negative(name: str, value: Any) -> float:
    v = real(name, value)
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


def integer(
    name: str, value: Any, *, minimum: int | None = None, maximum: int | None = None
) -> int:
    if not isinstance(value, (numbers.Integral, np.integer)) or isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__} {value!r}")
    v = int(value)
    if minimum is not None and v < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {v}")
    if maximum is not None and v > maximum:
        raise ValueError(f"{name} must be an integer <= {maximum}, got {v}")
    return v


def available_cores() -> int:
    """The CPUs this process may run on (its affinity mask): the kernels' default thread count."""
    from . import _core

    return int(_core.build_info()["default_threads"])


#: The largest count the native core takes (a C int): beyond, pybind11 raised its own TypeError.
MAX_NATIVE_INT = 2**31 - 1


def threads(value: Any) -> int:
    """None or 0 means every core this process may use."""
    if value is None:
        return 0
    return integer("threads", value, minimum=0, maximum=MAX_NATIVE_INT)


def not_masked(name: str, value: Any) -> None:
    """A masked array (``numpy.ma``) is a TypeError naming ``name``: nothing in this package
    reads a mask (the kernels read the data), so its masked elements would be used as values,
    silently. The caller says what they stand for with ``value.filled(...)``."""
    if isinstance(value, np.ma.MaskedArray):
        raise TypeError(
            f"{name} must not be a masked array (its mask would be ignored: the masked elements "
            f"would be used as values); pass {name}.filled(...) with the value they stand for "
            f"(NaN marks a hole in a disparity or depth map), got MaskedArray with dtype "
            f"{value.dtype}"
        )


def array(name: str, value: Any) -> np.ndarray:
    """``value`` as a numpy array (a numpy array as it is); a ragged nested list (rows of
    different lengths) or anything else numpy cannot turn into an array is a ValueError naming
    ``name`` and showing the value, not numpy's own "setting an array element with a sequence"
    or "inhomogeneous shape". A masked array is a TypeError (:func:`not_masked`)."""
    not_masked(name, value)
    if isinstance(value, np.ndarray):
        return value
    try:
        return np.asarray(value)
    except (ValueError, TypeError) as exc:
        shown = repr(value)
        shown = shown if len(shown) <= 80 else shown[:77] + "..."
        raise ValueError(
            f"{name} must be a rectangular array (every row of the same length), got "
            f"{type(value).__name__} {shown}"
        ) from exc


def disparity_array(name: str, value: Any) -> np.ndarray:
    """:func:`array` for a disparity map: a masked array (``numpy.ma``) is a TypeError naming
    ``name``, since the kernels read its data and would give the masked pixels a depth or a
    point, silently; NaN marks a hole (``d.filled(np.nan)``)."""
    if isinstance(value, np.ma.MaskedArray):
        raise TypeError(
            f"{name} must not be a masked array (its mask would be ignored: the masked pixels "
            f"would get values); mark the holes with NaN, {name}.filled(numpy.nan), got "
            f"MaskedArray with dtype {value.dtype}"
        )
    return array(name, value)


def real_array(name: str, value: Any) -> np.ndarray:
    """A scalar or array of real numbers as a float64 array (NaN and inf allowed); ValueError
    naming ``name`` for a Python int beyond a double."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be a real number or array, got bool {value!r}")
    not_masked(name, value)
    try:
        arr = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise TypeError(f"{name} must be a real number or array, got {value!r}") from exc
    if arr.dtype == object and arr.size and all(_is_real(v) for v in arr.flat):
        # Python ints beyond int64 (2**64, 10**20), which numpy keeps as objects: a double
        # holds them; one beyond a double (10**400) is real()'s ValueError naming the range.
        return np.array([real(name, v) for v in arr.flat], dtype=np.float64).reshape(arr.shape)
    if arr.dtype.kind not in "iuf":
        raise TypeError(
            f"{name} must be a real number or array, got {type(value).__name__} "
            f"with dtype {arr.dtype}"
        )
    return arr.astype(np.float64, copy=False)
