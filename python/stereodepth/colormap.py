"""Colour maps for disparity and depth maps: :func:`colorize` and :func:`save_colorized`.

A disparity map stored as numbers (or a 16-bit PNG of disparity x 256, or depth in mm) looks
black in an image viewer: its values use a sliver of the range. :func:`colorize` maps the
values through a perceptual colour map between two limits, and :func:`save_colorized` writes
that picture with a colour bar and its unit underneath, for a figure or a quick look.

The colour maps are matplotlib's (the ``plot`` extra: ``pip install "stereodepth[plot]"``),
sampled at 256 evenly spaced points. Default: ``"turbo"`` (Google's improved rainbow,
A. Mikhailov, 2019), which keeps neighbouring disparities apart; ``"viridis"`` and
``"magma"`` are perceptually uniform alternatives.
"""

from __future__ import annotations

import io as _stdio
import math
import numbers
import os
from pathlib import Path
from typing import Any

import numpy as np

from . import _validate as check

__all__ = [
    "LUT_SIZE",
    "colorize",
    "colorize_limits",
    "colormap_lut",
    "save_colorized",
    "to_uint8",
]

#: How many colours a colour map is sampled at: values fall into LUT_SIZE equal bins.
LUT_SIZE = 256
#: The default limits are these percentiles of the valid values (robust to outliers).
DEFAULT_PERCENTILES = (1.0, 99.0)

_INSTALL_HINT = 'colour maps need matplotlib: pip install "stereodepth[plot]"'


def _colormaps() -> Any:
    try:
        import matplotlib
    except ImportError as exc:
        raise ImportError(_INSTALL_HINT) from exc
    return matplotlib.colormaps


def colormap_lut(cmap: Any = "turbo") -> np.ndarray:
    """The colour map ``cmap`` (a matplotlib name, or a matplotlib ``Colormap``) as a
    (LUT_SIZE, 3) uint8 RGB table: its colours at ``numpy.linspace(0, 1, LUT_SIZE)``, each
    channel rounded to the nearest of 0..255. Raises ValueError for an unknown name, TypeError
    for anything else, ImportError (with the install hint) without matplotlib."""
    maps = _colormaps()
    if isinstance(cmap, str):
        if cmap not in maps:
            some = ", ".join(repr(n) for n in ("turbo", "viridis", "magma", "plasma", "gray"))
            raise ValueError(
                f"cmap must be a matplotlib colour map name such as {some}, got {cmap!r}"
            )
        cm = maps[cmap]
    else:
        from matplotlib.colors import Colormap

        if not isinstance(cmap, Colormap):
            raise TypeError(
                f"cmap must be a colour map name or a matplotlib Colormap, got "
                f"{type(cmap).__name__} {cmap!r}"
            )
        cm = cmap
    rgba = np.asarray(cm(np.linspace(0.0, 1.0, LUT_SIZE)), dtype=np.float64)
    return np.asarray(np.rint(rgba[:, :3] * 255.0), dtype=np.uint8)


def _values(values: Any) -> np.ndarray:
    if isinstance(values, (bool, np.bool_)) or (
        isinstance(values, np.ndarray) and values.dtype == np.bool_
    ):
        raise TypeError("values must be a 2-D array of real numbers, got bool")
    check.not_masked("values", values)
    try:
        arr = np.asarray(values)
    except (TypeError, ValueError) as exc:  # ragged lists and the like
        raise TypeError(f"values must be a 2-D array of real numbers, got {values!r}") from exc
    if arr.dtype.kind not in "iuf":
        raise TypeError(
            f"values must be a 2-D array of real numbers, got {type(values).__name__} with "
            f"dtype {arr.dtype}"
        )
    if arr.ndim != 2 or 0 in arr.shape:
        raise ValueError(f"values must be a non-empty 2-D (H, W) array, got shape {arr.shape}")
    return arr.astype(np.float64, copy=False)


def _limit(name: str, value: Any) -> float | None:
    if value is None:
        return None
    if not isinstance(value, numbers.Real) or isinstance(value, (bool, np.bool_)):
        raise TypeError(
            f"{name} must be a real number or None, got {type(value).__name__} {value!r}"
        )
    # An int beyond a double (10**400) raised Python's OverflowError, naming no parameter.
    return check.finite(name, value)


def _colour(value: Any) -> tuple[int, int, int]:
    rule = "invalid_color must be three integers from 0 to 255 (R, G, B)"
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{rule}, got {value!r}")
    try:
        items = tuple(value)
    except TypeError:
        raise TypeError(f"{rule}, got {type(value).__name__} {value!r}") from None
    if len(items) != 3:
        raise ValueError(f"{rule}, got {len(items)} values {value!r}")
    out = []
    for v in items:
        if not isinstance(v, (numbers.Integral, np.integer)) or isinstance(v, (bool, np.bool_)):
            raise TypeError(f"{rule}, got {value!r}")
        if not 0 <= int(v) <= 255:
            raise ValueError(f"{rule}, got {value!r}")
        out.append(int(v))
    return out[0], out[1], out[2]


def _resolve_limits(
    arr: np.ndarray, valid: np.ndarray, vmin: float | None, vmax: float | None
) -> tuple[float, float]:
    if vmin is not None and vmax is not None and not vmin < vmax:
        raise ValueError(f"vmin must be < vmax, got vmin={vmin!r} and vmax={vmax!r}")
    if (vmin is None or vmax is None) and valid.any():
        finite = arr[valid]
        if math.isfinite(float(finite.max()) - float(finite.min())):
            lo_p, hi_p = np.percentile(finite, DEFAULT_PERCENTILES)
        else:  # a range beyond float64 (values near its limits): interpolate the halves
            lo_p, hi_p = 2.0 * np.percentile(finite / 2, DEFAULT_PERCENTILES)
        lo = float(lo_p) if vmin is None else vmin
        hi = float(hi_p) if vmax is None else vmax
    else:
        lo = 0.0 if vmin is None else vmin
        hi = 1.0 if vmax is None else vmax
    if hi < lo:  # one limit given, the other a percentile beyond it
        lo, hi = (lo, lo) if vmin is not None else (hi, hi)
    return lo, hi


def colorize_limits(
    values: Any, *, vmin: float | None = None, vmax: float | None = None
) -> tuple[float, float]:
    """The limits :func:`colorize` uses for ``values``: ``vmin`` and ``vmax`` where given, else
    the 1st and 99th percentile (linear interpolation, numpy's default) of the finite values;
    (0, 1) when no value is finite. A given limit wins over a percentile beyond it: then both
    limits are that value. Raises as :func:`colorize`."""
    arr = _values(values)
    return _resolve_limits(arr, np.isfinite(arr), _limit("vmin", vmin), _limit("vmax", vmax))


def colorize(
    values: Any,
    *,
    cmap: Any = "turbo",
    vmin: float | None = None,
    vmax: float | None = None,
    invalid_color: Any = (0, 0, 0),
) -> np.ndarray:
    """A disparity or depth map (or any 2-D real array) as a (H, W, 3) uint8 RGB image.

    Parameters
    ----------
    values
        (H, W) array of real numbers, any integer or float dtype. NaN and infinities are
        invalid (a hole in a disparity map, no depth).
    cmap
        A matplotlib colour map name (default ``"turbo"``) or ``Colormap``; see
        :func:`colormap_lut`.
    vmin, vmax
        The values shown as the first and the last colour; values beyond them are clipped to
        those colours. Default: the 1st and 99th percentile of the finite values (so a few
        outliers do not wash the map out); see :func:`colorize_limits`.
    invalid_color
        The RGB colour of invalid pixels, three integers 0..255 (default black).

    Returns
    -------
    (H, W, 3) uint8. A valid value v gets colour ``lut[k]`` of :func:`colormap_lut`, with
    ``t = clip((v - vmin) / (vmax - vmin), 0, 1)`` and ``k = rint(t * (LUT_SIZE - 1))``
    (round half to even); when vmin == vmax, ``t`` is 0 below, 1 above and 0.5 at the value.

    Raises TypeError for a wrong type (values not real, bool, a limit not a number), ValueError
    for a wrong value or shape (not 2-D, empty, a non-finite limit, vmin >= vmax, an unknown
    colour map, a colour outside 0..255), ImportError with the install hint without matplotlib.
    """
    arr = _values(values)
    lo_in, hi_in = _limit("vmin", vmin), _limit("vmax", vmax)
    bad = _colour(invalid_color)
    lut = colormap_lut(cmap)
    valid = np.isfinite(arr)
    lo, hi = _resolve_limits(arr, valid, lo_in, hi_in)
    v = np.where(valid, arr, lo)
    if hi > lo:
        # Clipped first, so that v - lo cannot overflow; halved where hi - lo would (values
        # near the float64 limits), which gives t to the rounding of the halves.
        v = np.clip(v, lo, hi)
        if math.isfinite(hi - lo):
            t = (v - lo) / (hi - lo)
        else:
            t = np.clip((v / 2 - lo / 2) / (hi / 2 - lo / 2), 0.0, 1.0)
    else:
        t = np.where(v < lo, 0.0, np.where(v > lo, 1.0, 0.5))
    index = np.rint(t * (LUT_SIZE - 1)).astype(np.intp)
    rgb = lut[index]
    rgb[~valid] = bad
    return rgb


# --- a figure: the colourised map with a colour bar ---------------------------------------------
#: Height in pixels of the colour bar strip under the map in :func:`colorbar_strip`.
COLORBAR_HEIGHT_PX = 64
#: Limits larger in magnitude are drawn on the colour bar in units of a power of ten.
_LARGEST_DRAWN = 1e300


def colorbar_strip(
    width_px: int,
    *,
    vmin: float,
    vmax: float,
    label: str,
    cmap: Any = "turbo",
    height_px: int = COLORBAR_HEIGHT_PX,
) -> np.ndarray:
    """A horizontal colour bar with ticks and ``label`` (e.g. ``"disparity (px)"``) as a
    (height_px, width_px, 3) uint8 RGB image on white, drawn with matplotlib's Agg canvas."""
    _colormaps()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap, Normalize
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    if width_px < 1 or height_px < 1:
        raise ValueError(f"the colour bar needs a size >= 1 px, got {width_px}x{height_px}")
    dpi = 100
    fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi, facecolor="white")
    canvas: Any = FigureCanvasAgg(fig)  # untyped methods: draw, buffer_rgba
    margin = min(0.06, 12.0 / width_px)
    ax = fig.add_axes((margin, 0.62, 1 - 2 * margin, 0.25))
    lut = colormap_lut(cmap).astype(np.float64) / 255.0
    from matplotlib.cm import ScalarMappable

    top = max(abs(vmin), abs(vmax))
    if top > _LARGEST_DRAWN:
        # matplotlib's bar computes vmax - vmin, which overflows beyond a double's range
        # (values near 1e308: its warning, then "Axis limits cannot be NaN or Inf"): the bar
        # is drawn in units of a power of ten, which the label names.
        exponent = math.floor(math.log10(top))
        vmin, vmax = vmin / 10.0**exponent, vmax / 10.0**exponent
        label = f"{label}, \u00d7 1e{exponent}"
    hi = vmax if vmax > vmin else vmin + 1e-9 * max(1.0, abs(vmin))
    mappable = ScalarMappable(norm=Normalize(vmin=vmin, vmax=hi), cmap=ListedColormap(lut))
    bar = fig.colorbar(mappable, cax=ax, orientation="horizontal")
    bar.locator = MaxNLocator(nbins=max(2, min(8, width_px // 70)))
    bar.update_ticks()
    bar.ax.tick_params(labelsize=7, length=2, pad=1)
    bar.outline.set_linewidth(0.5)
    fig.text(0.5, 0.04, label, ha="center", va="bottom", fontsize=8)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    return np.ascontiguousarray(rgba[:height_px, :width_px, :3])


def preview_image(
    values: Any,
    *,
    label: str,
    cmap: Any = "turbo",
    vmin: float | None = None,
    vmax: float | None = None,
    invalid_color: Any = (0, 0, 0),
) -> np.ndarray:
    """:func:`colorize` of ``values`` with :func:`colorbar_strip` under it: a
    (H + COLORBAR_HEIGHT_PX, W, 3) uint8 RGB image whose top H rows are exactly ``colorize``'s."""
    rgb = colorize(values, cmap=cmap, vmin=vmin, vmax=vmax, invalid_color=invalid_color)
    lo, hi = colorize_limits(values, vmin=vmin, vmax=vmax)
    strip = colorbar_strip(rgb.shape[1], vmin=lo, vmax=hi, label=label, cmap=cmap)
    return np.concatenate([rgb, strip], axis=0)


def to_uint8(image: Any) -> np.ndarray:
    """An image as uint8 for display or point colours, the shape kept: uint8 as it is; uint16
    (grey or RGB) stretched from its own min..max to 0..255 (rounded), the stretch the
    matchers apply before matching (:mod:`stereodepth.matching`, step 1), so that a 12-bit
    or narrow-band image shows what was matched instead of its high byte (0..15 for 12-bit
    data: black); a constant uint16 image keeps its high byte. Raises TypeError for another
    dtype."""
    check.not_masked("image", image)
    a = np.asarray(image)
    if a.dtype == np.uint8:
        return a
    if a.dtype != np.uint16:
        raise TypeError(f"image must have dtype uint8 or uint16, got {a.dtype}")
    if a.size == 0:
        return a.astype(np.uint8)
    lo, hi = int(a.min()), int(a.max())
    if hi == lo:
        return (a >> 8).astype(np.uint8)
    scaled = (a.astype(np.float32) - lo) * np.float32(255.0 / (hi - lo))
    out: np.ndarray = np.rint(scaled).astype(np.uint8)
    return out


def png_bytes(rgb: np.ndarray, *, compress_level: int = 6) -> bytes:
    """An (H, W, 3) or (H, W) uint8 array as PNG bytes (Pillow, which matplotlib installs)."""
    from PIL import Image

    buf = _stdio.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(
        buf, format="PNG", compress_level=compress_level
    )
    return buf.getvalue()


def save_colorized(
    path: str | os.PathLike[str],
    values: Any,
    *,
    quantity: str = "disparity",
    unit: str = "px",
    cmap: Any = "turbo",
    vmin: float | None = None,
    vmax: float | None = None,
    invalid_color: Any = (0, 0, 0),
) -> Path:
    """Writes :func:`preview_image` of ``values`` as an RGB PNG, atomically, and returns the
    path: the colourised map pixel for pixel, and under it a colour bar labelled
    ``"<quantity> (<unit>)"``, e.g. ``disparity (px)`` or ``depth (m)``.

    ``path`` must end in ``.png`` and its folder exist (ValueError otherwise); the other
    parameters and errors are :func:`colorize`'s."""
    from .io import atomic_write

    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a str or os.PathLike, got {type(path).__name__} {path!r}")
    out = Path(path)
    if out.suffix.lower() != ".png":
        raise ValueError(f"path must end in .png, got {str(out)!r}")
    if not out.parent.is_dir():
        from .io import no_folder_reason

        why = no_folder_reason(out)
        raise ValueError(f"path's folder must exist: {why}, got {str(out)!r}")
    for name, text in (("quantity", quantity), ("unit", unit)):
        if not isinstance(text, str):
            raise TypeError(f"{name} must be a str, got {type(text).__name__} {text!r}")
    label = f"{quantity} ({unit})" if unit else quantity
    image = preview_image(
        values, label=label, cmap=cmap, vmin=vmin, vmax=vmax, invalid_color=invalid_color
    )
    data = png_bytes(image, compress_level=1)  # a preview: 4x faster than level 6
    with atomic_write(out) as f:
        f.write(data)
    return out
