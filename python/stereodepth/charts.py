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

__all__ = ["PLOT_RANGE", "Chart", "Charts", "Marker", "Series", "chart_data", "check_chartable"]

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
#: The numbers a drawn chart shows (disparities in px, depths and depth errors in m): on log
#: axes spanning several hundred decades matplotlib's axis arithmetic overflows a double (a
#: RuntimeWarning, or "Data cannot be log-scaled" when every point had overflowed).
PLOT_RANGE = (1e-100, 1e100)


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


def _chartable_disparities(rig: StereoRig, steps: tuple[float, ...]) -> tuple[float, float, float]:
    """The disparities (px) whose own value, depth and depth error for every step in
    ``steps`` lie in PLOT_RANGE: an interval, as depth and error fall with the disparity
    (computed in log10, as B*f and the bounds may be far apart); and the smallest disparity
    whose depth and errors do (a target <= 0 of a rig with doffs > 0 is off the log axis)."""
    low, high = (math.log10(v) for v in PLOT_RANGE)
    bf = math.log10(rig._bf_m_px)
    # the depth: in PLOT_RANGE itself, and its error Z * Z / (B f) * step too
    z_lo = max(low, 0.5 * (low + bf - math.log10(min(steps))))
    z_hi = min(high, 0.5 * (high + bf - math.log10(max(steps))))
    if z_lo > z_hi:
        return math.inf, -math.inf, math.inf

    def clamp(e: float) -> float:
        return float(10.0 ** min(max(e, -300.0), 300.0))

    # d + doffs = B f / Z
    floor = clamp(bf - z_hi) - rig.doffs_px
    d_lo = max(PLOT_RANGE[0], floor)
    d_hi = min(PLOT_RANGE[1], clamp(bf - z_lo) - rig.doffs_px)
    return d_lo, d_hi, floor


def _fits(
    rig: StereoRig, target: float | None, limit: float | None, d_lo: float, d_hi: float
) -> bool:
    lo, hi = _disparity_range(rig, target, limit)
    return d_lo <= lo and hi <= d_hi


def check_chartable(
    rig: StereoRig,
    *,
    disparity_px: float | None = None,
    disparity_step_px: float = 1.0,
    max_disparity_px: float | None = None,
) -> None:
    """Raises ValueError naming the parameter, its value and the values that can be drawn
    when the charts of :func:`chart_data` (arguments checked there) would hold a number
    outside PLOT_RANGE: a disparity, depth or depth error that a drawn log axis cannot show
    (the calculator's results take such values; only drawing refuses them)."""
    steps = (1.0,) if disparity_step_px == 1.0 else (1.0, disparity_step_px)
    d_lo, d_hi, floor = _chartable_disparities(rig, steps)
    shift = max(0.0, -rig.doffs_px)
    shown = f"{PLOT_RANGE[0]:g} to {PLOT_RANGE[1]:g}"
    why = f"the charts show disparities (px), depths and depth errors (m) from {shown} only"
    if d_lo > d_hi or (max_disparity_px is None and not _fits(rig, None, None, d_lo, d_hi)):
        lo, hi = _disparity_range(rig, None, max_disparity_px)
        with_step = "" if len(steps) == 1 else f" with disparity_step_px {steps[1]:g}"
        raise ValueError(
            f"this rig (B*f = {rig._bf_m_px:g} m*px, doffs_px {rig.doffs_px:g}){with_step} "
            f"cannot be charted: {why}, and its disparities {lo:g} to {hi:g} px give depths or "
            "depth errors outside that"
        )
    if max_disparity_px is not None and not _fits(rig, None, max_disparity_px, d_lo, d_hi):
        # above 1 px the axis runs from 1 px to it; at or below, from a quarter of it
        ok: list[tuple[float, float]] = []
        if 1.0 + shift >= d_lo and d_hi - shift > 1.0:
            ok.append((1.0, d_hi - shift))
        if 4 * (d_lo - shift) <= min(1.0, d_hi - shift):
            ok.append((max(4 * (d_lo - shift), 0.0), min(1.0, d_hi - shift)))
        span = ""
        if ok:
            low, high = min(a for a, _ in ok), max(b for _, b in ok)
            span = f"from {low:.4g} to {high:.4g} px" if low > 0 else f"up to {high:.4g} px"
        raise ValueError(
            f"max_disparity_px {max_disparity_px:g} cannot be charted: {why}"
            + (f"; for this rig it can be {span}" if span else "")
        )
    if disparity_px is None:
        return
    t = disparity_px
    in_range = _fits(rig, t, max_disparity_px, d_lo, d_hi)
    if in_range:  # the target's own marks: its depth and errors (a t <= 0 is off the axis)
        zt = float(rig._depth_unchecked(np.asarray(t, dtype=np.float64))[0])
        marks = [zt] + [float(rig._resolution_unchecked(np.asarray(zt), s)) for s in steps]
        if t > 0:
            marks.append(t)
        in_range = all(
            PLOT_RANGE[0] <= v <= PLOT_RANGE[1] for v in marks if math.isfinite(v) and v > 0
        )
    if not in_range:
        high = (d_hi - shift) / _MARGIN
        if d_lo - shift <= 0:  # any the calculator takes, up to high
            span = f"up to {high:.4g} px"
        else:
            span = f"from {_MARGIN * (d_lo - shift):.4g} to {high:.4g} px"
            if rig.doffs_px > 0 and floor <= 0:  # and some at or below 0, off the axis
                span = f"from {max(floor, -rig.doffs_px):.4g} to 0 or {span}"
        raise ValueError(
            f"disparity_px {t:g} cannot be charted: {why}; for this rig it can be {span}"
        )
