"""The calculator's two charts as an image, for ``stereodepth calc --plot``: matplotlib.

The data come from :func:`stereodepth.charts.chart_data`, as on the web page. Needs
matplotlib (the ``plot`` extra): ``pip install "stereodepth[plot]"``. Drawing uses the Agg
canvas directly (no pyplot, no global state), so it is safe from several threads.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from . import _validate as check
from .charts import PLOT_RANGE, Chart, Charts, chart_data, check_chartable
from .io import atomic_write
from .rig import StereoRig

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["draw_charts", "save_charts"]

#: The image formats save_charts writes, by file suffix.
FORMATS: dict[str, str] = {".png": "png", ".svg": "svg", ".pdf": "pdf"}

# The web page's colours: curves in blue and amber, the target in red.
_SERIES_COLOURS = ("#2563eb", "#d97706", "#059669")
_TARGET_COLOUR = "#dc2626"


def _matplotlib() -> None:
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError('the charts need matplotlib: pip install "stereodepth[plot]"') from exc


def _label(chart: Chart, name: str, y: float) -> str:
    what = "Z" if chart.y_label.startswith("depth Z") else "ΔZ"
    step = name.partition(", ")[2]
    return f"{what} = {y:.4g} m" + (f" ({step})" if step else "")


def _draw(ax: Axes, chart: Chart) -> None:
    import math

    # the scales first: set on drawn data, they autoscale there and then (and warn)
    if chart.x_log:
        ax.set_xscale("log")
    if chart.y_log:
        ax.set_yscale("log")
    # A curve flat to a double (depth B*f/doffs for disparities far below doffs) or a lone
    # point: a decade either side, set before plotting (matplotlib warned of singular limits).
    xs = [v for s in chart.series for v in s.x] + [m.x for m in chart.markers]
    ys = [v for s in chart.series for v in s.y] + [m.y for m in chart.markers]
    for values, axis in ((xs, ax.xaxis), (ys, ax.yaxis)):
        shown = [v for v in values if v > 0]
        if shown and min(shown) == max(shown):
            ax.autoscale(False, axis="x" if axis is ax.xaxis else "y")
            axis.set_view_interval(shown[0] / 10, shown[0] * 10, ignore=True)
    for i, s in enumerate(chart.series):
        lone = (
            len(set(zip(s.x, s.y, strict=True))) == 1
        )  # a flat curve's one point: a line of no length
        ax.plot(
            s.x,
            s.y,
            color=_SERIES_COLOURS[i % len(_SERIES_COLOURS)],
            lw=2,
            marker="o" if lone else None,
            label=s.name,
        )
    xs = [x for s in chart.series for x in s.x]
    for i, m in enumerate(chart.markers):
        if (chart.x_log and not m.x > 0) or (chart.y_log and not m.y > 0):
            # A log axis has no place for it: the target disparity 0 of a rig with doffs > 0,
            # whose depth is finite (chart_data keeps it: its other chart shows that depth).
            continue
        edge = _SERIES_COLOURS[i % len(_SERIES_COLOURS)] if len(chart.markers) > 1 else "white"
        if i == 0:
            ax.axvline(m.x, color=_TARGET_COLOUR, lw=0.8, ls=":", zorder=1)
        ax.plot(
            [m.x],
            [m.y],
            ls="none",
            marker="D",
            ms=8,
            color=_TARGET_COLOUR,
            markeredgecolor=edge,
            markeredgewidth=1.5,
            label=m.name,
            zorder=3,
        )
        # Label on the side with more room: left of a point in the right part of the axis.
        right_part = (
            bool(xs)
            and chart.x_log
            and min(xs) < max(xs)
            and (math.log(m.x / min(xs)) / math.log(max(xs) / min(xs)) > 0.6)
        )
        ax.annotate(
            _label(chart, m.name, m.y),
            (m.x, m.y),
            xytext=(-10 if right_part else 10, 0),
            textcoords="offset points",
            fontsize=8,
            color=_TARGET_COLOUR,
            va="center",
            ha="right" if right_part else "left",
            zorder=4,
            bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": "#fecaca", "lw": 0.8},
        )
    ax.set_title(chart.title, fontsize=11, loc="left", fontweight="bold")
    ax.set_xlabel(chart.x_label)
    ax.set_ylabel(chart.y_label)
    ax.grid(True, which="major", color="#d4d4d8", lw=0.8)
    ax.grid(True, which="minor", color="#f0f0f2", lw=0.5)
    if chart.series or chart.markers:
        ax.legend(fontsize=8, frameon=False, loc="best")


def draw_charts(charts: Charts, *, title: str | None = None) -> Figure:
    """The two charts side by side on a new matplotlib Figure (Agg canvas), under ``title``."""
    _matplotlib()
    for chart in (charts.depth_vs_disparity, charts.error_vs_depth):
        values = [v for s in chart.series for v in (*s.x, *s.y)]
        values += [v for m in chart.markers for v in (m.x, m.y) if v > 0]
        if not all(PLOT_RANGE[0] <= v <= PLOT_RANGE[1] for v in values):
            raise ValueError(
                f"the chart {chart.title!r} cannot be drawn: its log axes show numbers from "
                f"{PLOT_RANGE[0]:g} to {PLOT_RANGE[1]:g} only, got "
                f"{min(values):g} to {max(values):g}"
            )
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.4), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2)
    _draw(left, charts.depth_vs_disparity)
    _draw(right, charts.error_vs_depth)
    if title:
        fig.suptitle(title, fontsize=9, color="#52525b", x=0.01, ha="left")
    return fig


def _format(path: Path) -> str:
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ValueError(f"the chart file must end in {', '.join(FORMATS)}, got {str(path)!r}")
    return fmt


def save_charts(
    rig: StereoRig,
    path: str | os.PathLike[str],
    *,
    disparity_px: float | None = None,
    disparity_step_px: float = 1.0,
    max_disparity_px: float | None = None,
    dpi: int = 120,
) -> Path:
    """Writes the charts of :func:`stereodepth.charts.chart_data` (depth vs disparity, depth
    error vs depth for 1 px and ``disparity_step_px``, the target ``disparity_px`` marked) to
    ``path`` (.png, .svg or .pdf) and returns the path.

    The file is written whole or not at all: to a temporary file in the same folder, then
    renamed over ``path``. Bad arguments raise before anything is written, and so do values
    the calculator takes but the charts cannot show (a disparity, depth or depth error
    outside :data:`stereodepth.charts.PLOT_RANGE`: ValueError naming the parameter and the
    values it can take for this rig)."""
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a str or os.PathLike, got {type(path).__name__} {path!r}")
    if not os.fspath(path):  # Path("") is "."
        raise ValueError("path must not be empty, got ''")
    out = Path(path)
    fmt = _format(out)
    if not out.parent.is_dir():
        from .io import no_folder_reason

        why = no_folder_reason(out)
        raise ValueError(f"the chart file's folder must exist: {why}, got {str(out)!r}")
    if not 10 <= check.integer("dpi", dpi, minimum=10) <= 1200:
        raise ValueError(f"dpi must be an integer from 10 to 1200, got {dpi!r}")
    charts = chart_data(
        rig,
        disparity_px=disparity_px,
        disparity_step_px=disparity_step_px,
        max_disparity_px=max_disparity_px,
    )
    check_chartable(  # values the calculator takes but a log axis cannot show
        rig,
        disparity_px=disparity_px,
        disparity_step_px=disparity_step_px,
        max_disparity_px=max_disparity_px,
    )
    fig = draw_charts(charts, title=repr(rig))
    with atomic_write(out) as f:  # never a half-written chart; a folder in the way is refused
        fig.savefig(f, format=fmt, dpi=dpi)
    return out
