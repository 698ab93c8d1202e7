"""The calculator's two charts as data: depth against disparity, depth error against depth.

:func:`chart_data` computes the curves and the marked target with :class:`StereoRig`'s own
methods. The web page draws them with plotly and ``stereodepth calc --plot`` with matplotlib
(:mod:`stereodepth.plotting`), so both show the same numbers as the calculator's results.
Both charts are log-log: depth is inversely proportional to disparity and the depth error
grows with the square of the depth, so both curves are straight lines over many decades.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _validate as check
from .rig import StereoRig

__all__ = ["Chart", "Charts", "Marker", "Series", "chart_data"]

#: Points per curve.
DEFAULT_POINTS = 200
#: The most points a curve may have (more cannot be drawn apart; a huge count would only
#: exhaust memory).
MAX_POINTS = 100_000
#: The top of the disparity axis when neither a search range nor an image width is given.
DEFAULT_MAX_DISPARITY_PX = 256.0
# Keep the axis range well inside float64 so that the range arithmetic cannot overflow.
_LARGEST = 1e300
# How far beyond the target the disparity axis reaches when the target lies outside its range.
_MARGIN = 1.25


@dataclass(frozen=True)
class Series:
    """One curve: ``x`` and ``y`` of equal length, finite and > 0 (for log axes)."""

    name: str
    x: tuple[float, ...]
    y: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "x": list(self.x), "y": list(self.y)}


@dataclass(frozen=True)
class Marker:
    """A marked point, such as the target of the calculation."""

    name: str
    x: float
    y: float

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "x": self.x, "y": self.y}


@dataclass(frozen=True)
class Chart:
    """A chart: its title, axis labels (with units), axis scales, curves and marked points."""

    title: str
    x_label: str
    y_label: str
    x_log: bool
    y_log: bool
    series: tuple[Series, ...]
    markers: tuple[Marker, ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "title": self.title,
            "x_label": self.x_label,
            "y_label": self.y_label,
            "x_log": self.x_log,
            "y_log": self.y_log,
            "series": [s.to_dict() for s in self.series],
            "markers": [m.to_dict() for m in self.markers],
        }


@dataclass(frozen=True)
class Charts:
    """The calculator's two charts."""

    depth_vs_disparity: Chart
    error_vs_depth: Chart

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: lists and finite floats only."""
        return {
            "depth_vs_disparity": self.depth_vs_disparity.to_dict(),
            "error_vs_depth": self.error_vs_depth.to_dict(),
        }


def _step_name(step: float) -> str:
    return f"{step:g} px disparity step"


def _disparity_range(
    rig: StereoRig, target_px: float | None, max_disparity_px: float | None
) -> tuple[float, float]:
    """The disparities to draw: 1 px (the max depth) up to the search range, the image width
    or 256 px, widened to hold the target; shifted by -doffs when that is positive."""
    if max_disparity_px is not None:
        hi = max_disparity_px
    elif rig.width_px is not None:
        hi = float(max(1, min(DEFAULT_MAX_DISPARITY_PX, rig.width_px - 1)))
    else:
        hi = DEFAULT_MAX_DISPARITY_PX
    lo = 1.0
    if target_px is not None and target_px > 0:
        lo = min(lo, target_px / _MARGIN)
        hi = max(hi, target_px * _MARGIN)
    hi = min(hi, _LARGEST)
    if hi <= lo:
        lo = hi / 4
    shift = max(0.0, -rig.doffs_px)  # disparities up to -doffs are at or beyond infinity
    return lo + shift, hi + shift


def _positive(x: np.ndarray, y: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
    keep = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    return tuple(float(v) for v in x[keep]), tuple(float(v) for v in y[keep])


def chart_data(
    rig: StereoRig,
    *,
    disparity_px: float | None = None,
    disparity_step_px: float = 1.0,
    max_disparity_px: float | None = None,
    points: int = DEFAULT_POINTS,
) -> Charts:
    """The curves of depth against disparity and of depth error against depth for ``rig``.

    The disparity axis runs from 1 px (the rig's max depth) to ``max_disparity_px`` (else the
    image width less one, at most 256 px; else 256 px), widened to hold the target
    ``disparity_px``. The depth error is the first-order ``StereoRig.depth_resolution_m`` for
    a 1 px step and, when ``disparity_step_px`` is not 1, for that step. The target is marked
    on both charts with the values the calculator reports. Points that are not finite and > 0
    (a point at infinity, an underflow) are left out, as log axes cannot show them.

    Raises TypeError / ValueError naming the parameter for a bad value (``points`` is an
    integer in [2, MAX_POINTS])."""
    step = check.positive("disparity_step_px", disparity_step_px)
    n = check.integer("points", points, minimum=2, maximum=MAX_POINTS)
    target: float | None = None
    if disparity_px is not None:
        target = check.real("disparity_px", disparity_px)
        rig.depth_m(target)  # the rig's rule for a disparity: finite and >= -doffs
    limit = (
        None if max_disparity_px is None else check.positive("max_disparity_px", max_disparity_px)
    )

    # Extreme rigs and targets overflow to inf or underflow to 0: those points are left out.
    with np.errstate(over="ignore", under="ignore"):
        lo, hi = _disparity_range(rig, target, limit)
        d = np.geomspace(lo, hi, n)
        z, _ = rig._depth_unchecked(d)  # the curve's own points: out-of-range ones left out
        dx, zy = _positive(d, z)

        # Depth error against depth: ascending depth, only where the depth is finite and > 0.
        z_err = np.sort(z[np.isfinite(z) & (z > 0)])
        steps = (1.0,) if step == 1.0 else (1.0, step)
        err_series = tuple(
            Series(_step_name(s), *_positive(z_err, rig._resolution_unchecked(z_err, s)))
            for s in steps
        )

        depth_markers: list[Marker] = []
        error_markers: list[Marker] = []
        if target is not None:
            zt = float(rig.depth_m(target))
            if math.isfinite(zt) and zt > 0:
                depth_markers.append(Marker("target", target, zt))
                for s in steps:
                    e = float(rig._resolution_unchecked(np.asarray(zt), s))
                    if math.isfinite(e) and e > 0:
                        error_markers.append(Marker(f"target, {s:g} px", zt, e))

    return Charts(
        depth_vs_disparity=Chart(
            title="Depth vs disparity",
            x_label="disparity d (px)",
            y_label="depth Z (m)",
            x_log=True,
            y_log=True,
            series=(Series("depth", dx, zy),),
            markers=tuple(depth_markers),
        ),
        error_vs_depth=Chart(
            title="Depth error vs depth",
            x_label="depth Z (m)",
            y_label="depth error ΔZ (m)",
            x_log=True,
            y_log=True,
            series=err_series,
            markers=tuple(error_markers),
        ),
    )
