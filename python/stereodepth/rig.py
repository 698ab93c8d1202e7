"""The stereo depth calculator: what a rig of given baseline, lens and sensor can measure.

Units are in the names: ``_mm`` millimetres, ``_um`` micrometres, ``_px`` pixels, ``_m``
metres, ``_deg`` degrees. Every method takes a scalar or a numpy array and answers in kind.

The model is the rectified pinhole pair: a point at depth Z appears in the two images with a
disparity d (pixels) such that ``Z = B * f_px / (d + doffs)``, where B is the baseline,
``f_px = focal_mm / pixel_mm`` is the focal length in pixels and doffs the difference of the
principal points (0 for most rigs). A disparity of -doffs (0 for most rigs) means a point at
infinity: depth inf; with doffs > 0 the points beyond B * f_px / doffs have negative
disparities.

Results that leave the range of a double: a result is ``inf`` only where the model's answer is
infinite (``d + doffs == 0``: a point at infinity, and its depth resolution). Where the
model's answer is finite but the double overflows (a disparity of 1e-300 px, a baseline of
1e300 mm), or where a positive depth, depth resolution or baseline would round to 0, the
method raises ValueError naming the parameter and the value that lead there, rather than
answer inf or 0 (which JSON would show as null, like a value the rig cannot give).
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, overload

import numpy as np

from . import _validate as check

__all__ = ["DepthTable", "StereoRig"]

ArrayLike = Any
#: The default disparities of StereoRig.table(): a 1-1.5-2 series from 1 to 256 px.
DEFAULT_TABLE_DISPARITIES_PX: tuple[float, ...] = (
    1,
    2,
    3,
    4,
    6,
    8,
    12,
    16,
    24,
    32,
    48,
    64,
    96,
    128,
    192,
    256,
)


@overload
def _answer(x: float, like: float) -> float: ...
@overload
def _answer(x: np.ndarray, like: np.ndarray) -> np.ndarray: ...
def _answer(x: Any, like: Any) -> Any:
    """A Python float for scalar input, an array for array input."""
    return float(x) if np.ndim(like) == 0 else np.asarray(x, dtype=np.float64)


@dataclass(frozen=True)
class DepthTable:
    """Rows of disparity, depth and depth resolution. Iterate for dicts, or render as text.

    ``columns`` is a sequence of str, ``rows`` a sequence of rows of real numbers, each as long
    as ``columns`` (kept as tuples of floats); TypeError or ValueError naming the one that is
    not (a row of the wrong length lost cells from the text, silently)."""

    columns: tuple[str, ...]
    rows: tuple[tuple[float, ...], ...]

    def __post_init__(self) -> None:
        cols = self.columns
        if isinstance(cols, str) or not isinstance(cols, (tuple, list)):
            raise TypeError(f"columns must be a tuple of str, got {type(cols).__name__} {cols!r}")
        if not all(isinstance(c, str) for c in cols):
            raise TypeError(f"columns must be a tuple of str, got {cols!r}")
        rows = self.rows
        if isinstance(rows, (str, bytes)) or not isinstance(rows, (tuple, list)):
            raise TypeError(
                f"rows must be a tuple of rows (tuples of numbers), got {type(rows).__name__} "
                f"{rows!r}"
            )
        out = []
        for i, row in enumerate(rows):
            if not isinstance(row, (tuple, list)) or len(row) != len(cols):
                raise ValueError(
                    f"rows[{i}] must be a tuple of {len(cols)} numbers (one per column), got "
                    f"{row!r}"
                )
            out.append(tuple(check.real(f"rows[{i}][{j}]", v) for j, v in enumerate(row)))
        object.__setattr__(self, "columns", tuple(cols))
        object.__setattr__(self, "rows", tuple(out))

    def to_records(self) -> list[dict[str, float]]:
        return [dict(zip(self.columns, r, strict=False)) for r in self.rows]

    def __iter__(self) -> Iterator[dict[str, float]]:
        return iter(self.to_records())

    def __len__(self) -> int:
        return len(self.rows)

    def _cells(self) -> list[list[str]]:
        return [[_fmt(v) for v in r] for r in self.rows]

    def to_text(self) -> str:
        """A plain-text table, columns right-aligned."""
        cells = self._cells()
        widths = [max(len(c), *(len(r[i]) for r in cells)) for i, c in enumerate(self.columns)]
        lines = ["  ".join(c.rjust(w) for c, w in zip(self.columns, widths, strict=False))]
        lines.append("  ".join("-" * w for w in widths))
        lines += ["  ".join(v.rjust(w) for v, w in zip(r, widths, strict=False)) for r in cells]
        return "\n".join(lines)

    def to_markdown(self) -> str:
        lines = ["| " + " | ".join(self.columns) + " |"]
        lines.append("|" + "|".join("---:" for _ in self.columns) + "|")
        lines += ["| " + " | ".join(r) + " |" for r in self._cells()]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.to_text()


#: The largest image width or height accepted: far beyond any sensor, small enough that
#: every derived number stays an ordinary float.
MAX_IMAGE_SIZE_PX = 1 << 24


def _image_size(name: str, value: int | None) -> int | None:
    if value is None:
        return None
    return check.integer(name, value, minimum=1, maximum=MAX_IMAGE_SIZE_PX)


def _out_of_range(
    name: str, values: np.ndarray, results: np.ndarray, bad: np.ndarray, what: str, unit: str
) -> ValueError:
    """The error for the first ``bad`` entry: ``name`` gave a result outside a double's range."""
    first = values[bad].flat[0] if values.ndim else values
    got = results[bad].flat[0] if results.ndim else results
    return ValueError(
        f"{name} must give a {what} that a double can hold (it overflows to inf or rounds "
        f"to 0), got {float(first)!r}, which gives {float(got)!r} {unit}"
    )


def _step_out_of_range(step: float, result: float, z: float, bf: float) -> ValueError:
    """The error for a depth resolution that a 1 px step keeps in range but ``step`` does not:
    the step is to blame (``--subpixel-px`` on the command line)."""
    return ValueError(
        f"disparity_step_px must give a depth resolution that a double can hold (it overflows "
        f"to inf or rounds to 0; depth {z!r} m, B*f = {bf!r} m*px), got {step!r}, which gives "
        f"{result!r} m"
    )


def _fmt(v: float) -> str:
    if math.isinf(v):
        return "inf"
    if math.isnan(v):
        return "nan"
    if v == 0 or 1e-3 <= abs(v) < 1e6:
        return f"{v:.6g}" if abs(v) >= 1 or v == 0 else f"{v:.4g}"
    return f"{v:.4e}"


class StereoRig:
    """A rectified stereo pair: baseline, focal length, pixel size and image size.

    >>> rig = StereoRig(baseline_mm=150, focal_mm=6, pixel_um=2.8, width_px=1280)
    >>> round(rig.depth_m(250), 4), round(rig.disparity_mm(250), 4)
    (1.2857, 0.7)
    """

    __slots__ = (
        "_baseline_mm",
        "_doffs_px",
        "_focal_mm",
        "_focal_px",
        "_height_px",
        "_pixel_um",
        "_width_px",
    )

    def __init__(
        self,
        baseline_mm: float,
        focal_mm: float,
        pixel_um: float,
        width_px: int | None = None,
        height_px: int | None = None,
    ) -> None:
        self._baseline_mm = check.positive("baseline_mm", baseline_mm)
        self._focal_mm: float | None = check.positive("focal_mm", focal_mm)
        self._pixel_um: float | None = check.positive("pixel_um", pixel_um)
        self._focal_px = self._focal_mm / (self._pixel_um / 1000.0)
        self._width_px = _image_size("width_px", width_px)
        self._height_px = _image_size("height_px", height_px)
        self._doffs_px = 0.0
        self._check_scale(f"focal_mm={focal_mm!r} and pixel_um={pixel_um!r}")

    @classmethod
    def from_pixels(
        cls,
        baseline_mm: float,
        focal_px: float,
        width_px: int | None = None,
        doffs_px: float = 0.0,
        height_px: int | None = None,
    ) -> StereoRig:
        """A rig from a calibration in pixels (focal length in pixels, principal point offset).

        The sensor's pixel size is unknown then, so :meth:`disparity_mm` is unavailable."""
        rig = cls.__new__(cls)
        rig._baseline_mm = check.positive("baseline_mm", baseline_mm)
        rig._focal_px = check.positive("focal_px", focal_px)
        rig._focal_mm = None
        rig._pixel_um = None
        rig._width_px = _image_size("width_px", width_px)
        rig._height_px = _image_size("height_px", height_px)
        rig._doffs_px = check.finite("doffs_px", doffs_px)
        rig._check_scale(f"focal_px={focal_px!r}")
        return rig

    def _check_scale(self, focal: str) -> None:
        """Rejects parameters whose products leave the range of a double, where every answer
        would be 0 or inf: a focal length of 0 or inf pixels, or a zero or infinite B * f."""
        tiny = sys.float_info.min
        if not tiny <= self._focal_px < math.inf:
            raise ValueError(
                f"{focal} give a focal length of {self._focal_px!r} px, outside the range of a "
                "double"
            )
        bf = self._bf_m_px
        if not tiny <= bf < math.inf:
            raise ValueError(
                f"baseline_mm={self._baseline_mm!r} with a focal length of {self._focal_px!r} px "
                f"gives B*f = {bf!r} m*px, outside the range of a double"
            )

    @classmethod
    def from_middlebury_calib(cls, path: str | os.PathLike[str]) -> StereoRig:
        """A rig from a Middlebury ``calib.txt`` (cam0, baseline, doffs, width, height)."""
        from .calib import read_middlebury_calib

        c = read_middlebury_calib(path)
        return cls.from_pixels(
            baseline_mm=c.baseline_mm,
            focal_px=c.focal_px,
            width_px=c.width_px,
            doffs_px=c.doffs_px,
            height_px=c.height_px,
        )

    # --- the rig's numbers -----------------------------------------------------------------
    @property
    def baseline_mm(self) -> float:
        return self._baseline_mm

    @property
    def focal_mm(self) -> float | None:
        return self._focal_mm

    @property
    def pixel_um(self) -> float | None:
        return self._pixel_um

    @property
    def focal_px(self) -> float:
        """The focal length in pixels: focal_mm / pixel size in mm."""
        return self._focal_px

    @property
    def width_px(self) -> int | None:
        return self._width_px

    @property
    def height_px(self) -> int | None:
        return self._height_px

    @property
    def doffs_px(self) -> float:
        return self._doffs_px

    def __repr__(self) -> str:
        """The Python call that builds this rig, ``eval``-able with StereoRig in scope."""
        if self._focal_mm is not None:
            core = (
                f"baseline_mm={self._baseline_mm!r}, focal_mm={self._focal_mm!r}, "
                f"pixel_um={self._pixel_um!r}"
            )
        else:
            core = f"baseline_mm={self._baseline_mm!r}, focal_px={self._focal_px!r}"
            if self._doffs_px:
                core += f", doffs_px={self._doffs_px!r}"
        if self._width_px is not None:
            core += f", width_px={self._width_px!r}"
        if self._height_px is not None:
            core += f", height_px={self._height_px!r}"
        # The call that builds this rig: a rig in pixels comes from from_pixels.
        maker = "StereoRig" if self._focal_mm is not None else "StereoRig.from_pixels"
        return f"{maker}({core})"

    def _key(self) -> tuple[Any, ...]:
        return tuple(getattr(self, name) for name in self.__slots__)

    def __eq__(self, other: object) -> bool:
        """Rigs are equal when they were given the same values (a rig in millimetres and
        micrometres is not equal to its :meth:`from_pixels` twin, whose focal_mm is None)."""
        if not isinstance(other, StereoRig):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    @property
    def _bf_m_px(self) -> float:
        """Baseline (m) times focal length (px): depth (m) times disparity (px)."""
        return self._baseline_mm / 1000.0 * self._focal_px

    # --- disparity and depth ---------------------------------------------------------------
    def _disparity(self, name: str, disparity_px: ArrayLike) -> np.ndarray:
        raw_dtype = getattr(disparity_px, "dtype", None)
        if raw_dtype is not None and np.dtype(raw_dtype) in (
            np.dtype(np.int16),
            np.dtype(np.uint16),
        ):
            # The map functions read int16 as OpenCV's x16 fixed point and uint16 as KITTI's
            # x256: read here as pixels, the same array gave depths 16 or 256 times apart.
            raise TypeError(
                f"{name} must be in pixels, got an array of {np.dtype(raw_dtype)}, the dtype of "
                "OpenCV's disparity x 16 (int16) or KITTI's x 256 (uint16): convert it with "
                "stereodepth.from_opencv_disparity or read_disparity_png16, or pass it to "
                "depth_map, which reads both formats"
            )
        d = check.real_array(name, disparity_px)
        with np.errstate(over="ignore"):  # 1e308 + 1e308: inf, > 0 (its depth is checked later)
            den = d + self._doffs_px
        # d + doffs >= 0: -doffs is the disparity of a point at infinity, so with doffs > 0
        # (Middlebury's cx1 > cx0) the points beyond B*f / doffs have negative disparities,
        # as disparity_px() gives them and the map kernels take them.
        bad = ~np.isfinite(d) | (den < 0)
        if np.any(bad):
            first = d[bad].flat[0] if d.ndim else d
            rule = f"finite and >= {-self._doffs_px + 0.0:g}"
            if self._doffs_px < 0:
                rule += (
                    f" (with doffs_px {self._doffs_px:g}, a disparity below "
                    f"{-self._doffs_px:g} px puts the point behind the cameras)"
                )
            elif self._doffs_px > 0:
                rule += (
                    f" (with doffs_px {self._doffs_px:g}, a disparity of {-self._doffs_px:g} px "
                    "is a point at infinity and one below it lies behind the cameras)"
                )
            raise ValueError(f"{name} must be {rule}, got {float(first)!r}")
        return d

    @overload
    def depth_m(self, disparity_px: float) -> float: ...
    @overload
    def depth_m(self, disparity_px: np.ndarray) -> np.ndarray: ...
    def depth_m(self, disparity_px: ArrayLike) -> Any:
        """Depth in metres of a disparity in pixels: B * f_px / (d + doffs).

        A disparity of -doffs (0 for most rigs) is a point at infinity: ``inf``; with doffs > 0
        the points beyond B * f_px / doffs have negative disparities. A disparity below -doffs
        (behind the cameras), NaN or infinite raises ValueError, and so does one whose depth
        leaves the range of a double (inf or 0 for a finite, positive depth). An int16 or
        uint16 array raises TypeError: those are OpenCV's and KITTI's fixed-point maps, which
        :meth:`depth_map` reads."""
        return self._depth_of("disparity_px", disparity_px)

    def _blamed(self, name: str) -> str:
        """A disparity's name for a result out of a double's range: with doffs, which shares
        the blame (``--doffs-px 1e308`` gave a depth of 0 that named only the disparity)."""
        return f"{name} (with doffs_px {self._doffs_px!r})" if self._doffs_px else name

    def _depth_of(self, name: str, disparity_px: ArrayLike) -> Any:
        """depth_m, naming the disparity ``name`` in its messages."""
        d = self._disparity(name, disparity_px)
        z, den = self._depth_unchecked(d)
        bad = (den != 0) & ~((z > 0) & (z < math.inf))
        if np.any(bad):
            raise _out_of_range(
                self._blamed(name),
                d,
                z,
                bad,
                f"depth (B*f / (d + doffs), B*f = {self._bf_m_px!r} m*px)",
                "m",
            )
        return _answer(z, d)

    def _depth_unchecked(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(depth, d + doffs) of checked disparities, inf or 0 where the double overflows
        (for the charts, which leave such points out)."""
        with np.errstate(divide="ignore", over="ignore", under="ignore"):
            den = d + self._doffs_px
            return self._bf_m_px / den, den

    @overload
    def disparity_px(self, depth_m: float) -> float: ...
    @overload
    def disparity_px(self, depth_m: np.ndarray) -> np.ndarray: ...
    def disparity_px(self, depth_m: ArrayLike) -> Any:
        """The disparity in pixels of a point at ``depth_m`` metres (> 0; inf gives -doffs).

        ValueError for a depth so small that its disparity overflows a double."""
        z = self._depth("depth_m", depth_m)
        with np.errstate(over="ignore", under="ignore"):
            d = self._bf_m_px / z - self._doffs_px
        bad = np.isfinite(z) & ~np.isfinite(d)
        if np.any(bad):
            raise _out_of_range("depth_m", z, d, bad, "disparity", "px")
        return _answer(d, z)

    def _depth(self, name: str, depth_m: ArrayLike) -> np.ndarray:
        z = check.real_array(name, depth_m)
        bad = np.isnan(z) | (z <= 0)
        if np.any(bad):
            first = z[bad].flat[0] if z.ndim else z
            raise ValueError(f"{name} must be > 0, got {float(first)!r}")
        return z

    def disparity_mm(self, disparity_px: ArrayLike) -> Any:
        """The disparity on the sensor in millimetres: d * pixel size."""
        if self._pixel_um is None:
            raise ValueError(
                "disparity_mm needs the pixel size: build the rig with StereoRig(baseline_mm, "
                "focal_mm, pixel_um) rather than from_pixels"
            )
        d = self._disparity("disparity_px", disparity_px)
        mm = self._disparity_mm_unchecked(d)
        bad = ~np.isfinite(mm)
        if np.any(bad):
            raise _out_of_range("disparity_px", d, mm, bad, "disparity on the sensor", "mm")
        return _answer(mm, d)

    def _disparity_mm_unchecked(self, d: np.ndarray) -> np.ndarray:
        assert self._pixel_um is not None
        with np.errstate(over="ignore", under="ignore"):
            return np.asarray(d * (self._pixel_um / 1000.0))

    @property
    def max_depth_m(self) -> float:
        """The depth at a disparity of 1 px, ``B*f / (1 + doffs)``: the far end of a search that
        starts at 1 px (:meth:`min_depth_m` gives the near end). Without ``doffs_px`` it is also
        the farthest a whole-pixel matcher can tell from infinity; with it, infinity lies at
        ``d = -doffs`` and the depth one pixel nearer is ``B*f`` (a Middlebury 2014 rig with
        doffs 53 px: 3.37 m here, 183 m there). ``inf`` when ``doffs_px <= -1``, where a
        disparity of 1 px is at or beyond infinity."""
        if 1.0 + self._doffs_px <= 0.0:
            return math.inf
        return float(self._depth_of("the disparity of 1 px (max depth)", 1.0))

    def min_depth_m(self, max_disparity_px: float) -> float:
        """The nearest depth a matcher searching disparities up to ``max_disparity_px`` sees."""
        d = check.positive("max_disparity_px", max_disparity_px)
        return float(self._depth_of("max_disparity_px", d))

    def depth_resolution_m(
        self, depth_m: ArrayLike, disparity_step_px: float = 1.0, *, exact: bool = False
    ) -> Any:
        """The depth error of a disparity error of ``disparity_step_px`` at ``depth_m``.

        By default the first-order estimate ``dZ = Z**2 * dd / (B * f_px)`` (equivalently
        Z²·p·Δd/(B·f) with the focal length and pixel size in the same unit), which grows with
        the square of the depth. With ``exact=True``, the exact difference ``Z(d) - Z(d + dd)``
        between the depth at the target's disparity d and the depth one step nearer; it is a
        little smaller than the estimate and the two agree as dd / d goes to 0. A depth of
        ``inf`` gives ``inf``; ValueError for a finite depth whose resolution overflows a
        double or rounds to 0."""
        z = self._depth("depth_m", depth_m)
        step = check.positive("disparity_step_px", disparity_step_px)
        if not isinstance(exact, bool):
            raise TypeError(f"exact must be a bool, got {type(exact).__name__} {exact!r}")
        dz = self._resolution_unchecked(z, step, exact=exact)
        bad = np.isfinite(z) & ~((dz > 0) & (dz < math.inf))
        if np.any(bad):
            self._blame_step(z[bad] if z.ndim else z, dz[bad] if z.ndim else dz, step, exact)
            raise _out_of_range(
                "depth_m",
                z,
                dz,
                bad,
                f"depth resolution (B*f = {self._bf_m_px!r} m*px, step {step!r} px)",
                "m",
            )
        return _answer(dz, z)

    def _blame_step(self, z: np.ndarray, dz: np.ndarray, step: float, exact: bool) -> None:
        """Raises the disparity_step_px error when the first depth whose resolution left the
        range keeps it with a 1 px step."""
        if step == 1.0:
            return
        z0 = np.asarray(z).flat[0]
        one = float(self._resolution_unchecked(np.asarray(z0), 1.0, exact=exact))
        if 0.0 < one < math.inf:
            raise _step_out_of_range(step, float(np.asarray(dz).flat[0]), float(z0), self._bf_m_px)

    def _resolution_unchecked(self, z: np.ndarray, step: float, *, exact: bool = False) -> Any:
        """depth_resolution_m of checked depths, inf or 0 where the double overflows (for the
        charts). Written so that no intermediate overflows or cancels where the result does
        not: Z * (Z / (B f)) * dd, and the exact Z(d) - Z(d + dd) = Z * dd / (d + doffs + dd)."""
        with np.errstate(over="ignore", under="ignore", invalid="ignore", divide="ignore"):
            if exact:
                den = self._bf_m_px / z  # d + doffs
                return z * step / (den + step)
            return z * (z / self._bf_m_px) * step

    def required_baseline_mm(
        self, depth_m: float, depth_resolution_m: float, disparity_step_px: float = 1.0
    ) -> float:
        """The baseline that gives a depth error of ``depth_resolution_m`` at ``depth_m``, with
        this rig's focal length and a matcher accurate to ``disparity_step_px``:
        ``B = Z**2 * dd / (dZ * f_px)`` (first order, as :meth:`depth_resolution_m`).

        ValueError when that baseline leaves the range of a double (names ``depth_m``)."""
        z = check.positive("depth_m", depth_m)
        dz = check.positive("depth_resolution_m", depth_resolution_m)
        step = check.positive("disparity_step_px", disparity_step_px)
        with np.errstate(over="ignore", under="ignore"):
            b = float(np.float64(z) * (z / dz) * (step / self._focal_px) * 1000.0)
        if not 0.0 < b < math.inf:
            # An intermediate may overflow or underflow where the answer does not: decide
            # in logarithms.
            log_b = (
                2 * math.log(z)
                + math.log(step)
                - math.log(dz)
                - math.log(self._focal_px)
                + math.log(1000.0)
            )
            if not math.log(sys.float_info.min) <= log_b < math.log(sys.float_info.max):
                raise ValueError(
                    f"depth_m must give a baseline that a double can hold (it overflows to inf "
                    f"or rounds to 0), got {z!r} with depth_resolution_m {dz!r} (focal length "
                    f"{self._focal_px!r} px, step {step!r} px), which gives about "
                    f"1e{log_b / math.log(10):+.0f} mm"
                )
            b = math.exp(log_b)
        return b

    # --- field of view ---------------------------------------------------------------------
    @property
    def hfov_deg(self) -> float:
        """The horizontal field of view, 2 atan(W / 2 f_px), in degrees (needs width_px)."""
        if self._width_px is None:
            raise ValueError("hfov_deg needs width_px, got None")
        return math.degrees(2.0 * math.atan(self._width_px / 2.0 / self._focal_px))

    @property
    def vfov_deg(self) -> float:
        """The vertical field of view in degrees (needs height_px)."""
        if self._height_px is None:
            raise ValueError("vfov_deg needs height_px, got None")
        return math.degrees(2.0 * math.atan(self._height_px / 2.0 / self._focal_px))

    # --- the table -------------------------------------------------------------------------
    def table(
        self,
        disparities_px: Sequence[float] | np.ndarray | None = None,
        *,
        disparity_step_px: float = 1.0,
    ) -> DepthTable:
        """Disparity, depth and depth resolution over ``disparities_px`` (default: a 1-1.5-2
        series from 1 to 256 px, capped below the image width when it is known).

        Columns: ``disparity_px``, ``disparity_mm`` (when the pixel size is known),
        ``depth_m``, ``depth_resolution_m`` (for a 1 px step) and, for another
        ``disparity_step_px``, ``depth_resolution_subpx_m``. ValueError for a disparity whose
        depth, depth resolution or disparity on the sensor leaves the range of a double."""
        if disparities_px is None:
            # Below the image width, and not below infinity (d + doffs >= 0).
            limit = self._width_px - 1 if self._width_px is not None else math.inf
            lowest = max(0.0, -self._doffs_px)
            ds = [float(d) for d in DEFAULT_TABLE_DISPARITIES_PX if lowest <= d <= limit]
            # (A float: math.ceil of 1e308 is an int numpy stores as an object array.)
            ds = ds or [max(1.0, float(math.ceil(lowest)))]
        else:
            arr = check.real_array("disparities_px", disparities_px)
            if arr.ndim != 1 or arr.size == 0:
                raise ValueError(
                    f"disparities_px must be a non-empty 1-D sequence, got shape {arr.shape}"
                )
            ds = [float(v) for v in arr]
        name = "the table's disparity" if disparities_px is None else "disparities_px"
        d = self._disparity(name, np.asarray(ds))
        step = check.positive("disparity_step_px", disparity_step_px)
        z = self._depth_of(name, d)
        res1 = self._resolution_unchecked(z, 1.0)
        resn = res1 if step == 1.0 else self._resolution_unchecked(z, step)
        for res, s in ((res1, 1.0), (resn, step)):
            bad = np.isfinite(z) & ~((res > 0) & (res < math.inf))
            if np.any(bad):
                self._blame_step(z[bad], res[bad], s, False)
                raise _out_of_range(
                    self._blamed(name),
                    d,
                    res,
                    bad,
                    f"depth resolution (B*f = {self._bf_m_px!r} m*px, step {s!r} px)",
                    "m",
                )
        columns: list[str] = ["disparity_px"]
        cols: list[np.ndarray] = [d]
        if self._pixel_um is not None:
            mm = self._disparity_mm_unchecked(d)
            if not np.isfinite(mm).all():
                raise _out_of_range(name, d, mm, ~np.isfinite(mm), "disparity on the sensor", "mm")
            columns.append("disparity_mm")
            cols.append(mm)
        columns += ["depth_m", "depth_resolution_m"]
        cols += [z, res1]
        if step != 1.0:
            columns.append("depth_resolution_subpx_m")
            cols.append(resn)
        rows = tuple(tuple(float(c[i]) for c in cols) for i in range(len(ds)))
        return DepthTable(columns=tuple(columns), rows=rows)

    # --- everything at once ---------------------------------------------------------------
    def summary(
        self,
        disparity_px: float | None = None,
        *,
        disparity_step_px: float = 1.0,
        max_disparity_px: float | None = None,
        table_disparities_px: Sequence[float] | np.ndarray | None = None,
        finite_only: bool = True,
    ) -> dict[str, Any]:
        """Every result of the calculator as one JSON-ready dict: what the CLI prints and the
        web page shows. Values that need something the rig lacks (the pixel size, the image
        width, a disparity) are None. So are infinite values (the depth at disparity 0, and
        its depth resolution), since JSON has no infinity; with ``finite_only=False`` they
        stay ``inf`` (for display: the CLI's text output and table show ``inf``).
        A result that the model makes finite but that leaves the range of a double raises
        ValueError naming the parameter that leads there (see the module docstring).

        Keys: ``focal_px``, ``max_depth_m``, ``hfov_deg``, ``vfov_deg``, ``disparity_px``,
        ``depth_m``, ``disparity_mm``, ``depth_resolution_m`` (1 px step, first order),
        ``depth_resolution_exact_m``, ``disparity_step_px``, ``depth_resolution_subpx_m``,
        ``max_disparity_px``, ``min_depth_m``, ``table`` (records as :meth:`table`)."""
        step = check.positive("disparity_step_px", disparity_step_px)
        out: dict[str, Any] = {
            "focal_px": self._focal_px,
            "max_depth_m": self.max_depth_m,
            "hfov_deg": self.hfov_deg if self._width_px is not None else None,
            "vfov_deg": self.vfov_deg if self._height_px is not None else None,
            "disparity_px": None,
            "depth_m": None,
            "disparity_mm": None,
            "depth_resolution_m": None,
            "depth_resolution_exact_m": None,
            "disparity_step_px": step,
            "depth_resolution_subpx_m": None,
            "max_disparity_px": None,
            "min_depth_m": None,
        }
        if disparity_px is not None:
            d = float(self._disparity("disparity_px", check.real("disparity_px", disparity_px)))
            z = float(self.depth_m(d))
            out["disparity_px"] = d
            out["depth_m"] = z
            if self._pixel_um is not None:
                out["disparity_mm"] = float(self.disparity_mm(d))
            if 0.0 < z < math.inf:
                za = np.asarray(z)
                for key, s, exact in (
                    ("depth_resolution_m", 1.0, False),
                    ("depth_resolution_exact_m", 1.0, True),
                    ("depth_resolution_subpx_m", step, False),
                ):
                    dz = float(self._resolution_unchecked(za, s, exact=exact))
                    if not 0.0 < dz < math.inf:  # named by what the caller gave: the disparity
                        self._blame_step(za, np.asarray(dz), s, exact)
                        raise _out_of_range(
                            self._blamed("disparity_px"),
                            np.asarray(d),
                            np.asarray(dz),
                            np.asarray(True),
                            f"depth resolution (depth {z!r} m, B*f = {self._bf_m_px!r} m*px, "
                            f"step {s!r} px)",
                            "m",
                        )
                    out[key] = dz
            elif z == math.inf:  # at infinity every disparity error is an infinite depth error
                out["depth_resolution_m"] = math.inf
                out["depth_resolution_exact_m"] = math.inf
                out["depth_resolution_subpx_m"] = math.inf
        if max_disparity_px is not None:
            out["max_disparity_px"] = check.positive("max_disparity_px", max_disparity_px)
            out["min_depth_m"] = self.min_depth_m(max_disparity_px)
        if not isinstance(finite_only, bool):
            raise TypeError(
                f"finite_only must be a bool, got {type(finite_only).__name__} {finite_only!r}"
            )
        table = self.table(table_disparities_px, disparity_step_px=step)

        def shown(v: Any) -> Any:
            if isinstance(v, float) and not math.isfinite(v) and (finite_only or math.isnan(v)):
                return None
            return v

        out["table"] = [{k: shown(v) for k, v in row.items()} for row in table]
        return {k: (v if k == "table" else shown(v)) for k, v in out.items()}

    # --- maps ------------------------------------------------------------------------------
    def _check_map_size(self, name: str, disparity: Any) -> None:
        """A (H, W) or (N, H, W) map must match the rig's image size where it has one."""
        if self._width_px is None and self._height_px is None:
            return
        shape = check.disparity_array(name, disparity).shape  # a ragged list named, not numpy's
        if len(shape) not in (2, 3):
            return  # disparity_to_depth names the shape
        h, w = shape[-2:]
        if (self._width_px is not None and w != self._width_px) or (
            self._height_px is not None and h != self._height_px
        ):
            want = f"{self._width_px if self._width_px is not None else 'any'} x " + (
                f"{self._height_px if self._height_px is not None else 'any'} px"
            )
            raise ValueError(
                f"{name} must have the rig's image size, {want} (its focal length in pixels and "
                f"doffs belong to that resolution), got {w} x {h} px: match at the calibrated "
                "size, or make a rig for this one"
            )

    def depth_map(self, disparity: Any, **options: Any) -> np.ndarray:
        """Converts a disparity map with this rig's numbers; see
        :func:`stereodepth.disparity_to_depth` for ``options`` (scale, dtype, limits, out,
        threads).

        When the rig has an image size (``width_px``, ``height_px``: a calibration file gives
        one), the map must have it: raises ValueError otherwise, since the focal length in
        pixels and doffs belong to that resolution (Middlebury's full-size ``calib.txt`` with
        its quarter-size images gives depths 4 times too large), as ``stereodepth match``
        refuses such a pair."""
        from .depth import disparity_to_depth

        self._check_map_size("disparity", disparity)

        return disparity_to_depth(
            disparity,
            focal_px=self._focal_px,
            baseline_m=self._baseline_mm / 1000.0,
            doffs_px=self._doffs_px,
            **options,
        )
