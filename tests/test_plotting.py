"""The charts: their data (stereodepth.charts) against the rig's own methods, and the image
that stereodepth.plotting draws from them with matplotlib, written atomically."""

from __future__ import annotations

import math
import os
import re
import struct
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereodepth import StereoRig
from stereodepth.charts import Charts, chart_data

ARM = StereoRig(150, 6, 2.8, width_px=1280)


# --- the data -------------------------------------------------------------------------------------
def test_depth_curve_is_the_rigs_depth() -> None:
    c = chart_data(ARM, disparity_px=250, disparity_step_px=0.25, max_disparity_px=256)
    (s,) = c.depth_vs_disparity.series
    d = np.array(s.x)
    assert np.array_equal(np.array(s.y), ARM.depth_m(d))
    assert d[0] == pytest.approx(1.0) and np.all(np.diff(d) > 0)
    assert d[-1] == pytest.approx(250 * 1.25)  # widened to hold the target beyond the range
    assert c.depth_vs_disparity.x_log and c.depth_vs_disparity.y_log


def test_error_curves_are_the_rigs_depth_resolution() -> None:
    c = chart_data(ARM, disparity_px=250, disparity_step_px=0.25)
    one, sub = c.error_vs_depth.series
    assert (one.name, sub.name) == ("1 px disparity step", "0.25 px disparity step")
    z = np.array(one.x)
    assert np.all(np.diff(z) > 0)
    assert np.array_equal(np.array(one.y), ARM.depth_resolution_m(z))
    assert np.array_equal(np.array(sub.y), ARM.depth_resolution_m(z, 0.25))
    assert z[-1] == ARM.max_depth_m  # 1 px


def test_markers_are_the_calculators_results() -> None:
    s = ARM.summary(250, disparity_step_px=0.25)
    c = chart_data(ARM, disparity_px=250, disparity_step_px=0.25)
    (t,) = c.depth_vs_disparity.markers
    assert (t.name, t.x, t.y) == ("target", 250.0, s["depth_m"])
    m1, m2 = c.error_vs_depth.markers
    assert (m1.name, m1.x, m1.y) == ("target, 1 px", s["depth_m"], s["depth_resolution_m"])
    assert (m2.name, m2.x, m2.y) == ("target, 0.25 px", s["depth_m"], s["depth_resolution_subpx_m"])


def test_whole_pixel_step_has_one_error_curve() -> None:
    c = chart_data(ARM, disparity_px=35)
    assert [s.name for s in c.error_vs_depth.series] == ["1 px disparity step"]
    assert [m.name for m in c.error_vs_depth.markers] == ["target, 1 px"]


def test_range_follows_search_range_width_and_target() -> None:
    def top(c: Charts) -> float:
        return c.depth_vs_disparity.series[0].x[-1]

    assert top(chart_data(ARM, max_disparity_px=64)) == pytest.approx(64)
    assert top(chart_data(ARM)) == pytest.approx(256)
    assert top(chart_data(StereoRig(150, 6, 2.8, width_px=100))) == pytest.approx(99)
    assert top(chart_data(StereoRig(150, 6, 2.8))) == pytest.approx(256)
    low = chart_data(ARM, disparity_px=0.2)
    assert low.depth_vs_disparity.series[0].x[0] == pytest.approx(0.2 / 1.25)


def test_point_at_infinity_is_not_marked() -> None:
    c = chart_data(ARM, disparity_px=0)
    assert c.depth_vs_disparity.markers == () and c.error_vs_depth.markers == ()
    assert len(c.depth_vs_disparity.series[0].x) == 200


def test_calibration_in_pixels_with_offset() -> None:
    rig = StereoRig.from_pixels(193.001, 3979.911, doffs_px=124.343, width_px=2964)
    c = chart_data(rig, disparity_px=0, points=50)
    s = c.depth_vs_disparity.series[0]
    assert len(s.x) == 50
    assert c.depth_vs_disparity.markers[0].y == rig.depth_m(0.0)  # finite thanks to doffs


def test_to_dict_is_json_ready() -> None:
    import json

    d = chart_data(ARM, disparity_px=250, disparity_step_px=0.5).to_dict()
    assert json.loads(json.dumps(d, allow_nan=False)) == d
    assert set(d) == {"depth_vs_disparity", "error_vs_depth"}
    assert d["error_vs_depth"]["y_label"] == "depth error ΔZ (m)"


@pytest.mark.parametrize(
    ("kwargs", "exc", "msg"),
    [
        ({"disparity_px": -1}, ValueError, "disparity_px must be finite and >= 0, got -1.0"),
        ({"disparity_px": math.nan}, ValueError, "disparity_px must be finite"),
        ({"disparity_px": "5"}, TypeError, "disparity_px must be a real number, got str '5'"),
        (
            {"disparity_step_px": 0},
            ValueError,
            "disparity_step_px must be a finite number > 0, got 0",
        ),
        (
            {"max_disparity_px": -3},
            ValueError,
            "max_disparity_px must be a finite number > 0, got -3",
        ),
        ({"points": 1}, ValueError, "points must be an integer >= 2, got 1"),
        ({"points": 2.5}, TypeError, "points must be an integer, got float 2.5"),
        ({"points": 10**12}, ValueError, "points must be an integer <= 100000, got 1000000000000"),
    ],
)
def test_chart_data_rejects(kwargs: dict[str, Any], exc: type[Exception], msg: str) -> None:
    with pytest.raises(exc) as info:
        chart_data(ARM, **kwargs)
    assert str(info.value).startswith(msg)


_pos = st.floats(min_value=1e-6, max_value=1e6)


@settings(max_examples=150, deadline=None)
@given(
    baseline=_pos,
    focal=_pos,
    pixel=_pos,
    # (A target below about 1e-296 px can overflow the depth: the rig's ValueError.)
    target=st.none() | st.just(0.0) | st.floats(1e-280, 1e6),
    step=st.floats(1e-6, 1e3),
    top=st.none() | _pos,
)
def test_curves_are_finite_positive_and_monotonic(
    baseline: float,
    focal: float,
    pixel: float,
    target: float | None,
    step: float,
    top: float | None,
) -> None:
    rig = StereoRig(baseline, focal, pixel)
    c = chart_data(
        rig, disparity_px=target, disparity_step_px=step, max_disparity_px=top, points=40
    )
    for chart in (c.depth_vs_disparity, c.error_vs_depth):
        for s in chart.series:
            x, y = np.array(s.x), np.array(s.y)
            assert len(x) == len(y)
            assert np.all(np.isfinite(x) & (x > 0) & np.isfinite(y) & (y > 0))
            assert np.all(np.diff(x) > 0)
        for m in chart.markers:
            assert math.isfinite(m.x) and m.x > 0 and math.isfinite(m.y) and m.y > 0
    z = np.array(c.depth_vs_disparity.series[0].y)
    assert np.all(np.diff(z) < 0)  # depth falls as disparity grows


# --- the image ------------------------------------------------------------------------------------
pytest.importorskip("matplotlib", reason="the plot extra is not installed")

from stereodepth.plotting import draw_charts, save_charts  # noqa: E402


def png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    w, h = struct.unpack(">II", head[16:24])
    return w, h


def test_figure_draws_the_chart_data() -> None:
    c = chart_data(ARM, disparity_px=250, disparity_step_px=0.25)
    fig = draw_charts(c, title="arm")
    left, right = fig.axes
    assert left.get_xscale() == "log" and right.get_yscale() == "log"
    assert left.get_xlabel() == "disparity d (px)" and right.get_ylabel() == "depth error ΔZ (m)"
    drawn = {line.get_label(): line.get_xydata() for line in left.lines + right.lines}
    for s in c.depth_vs_disparity.series + c.error_vs_depth.series:
        assert np.array_equal(drawn[s.name], np.column_stack((s.x, s.y)))
    for m in c.depth_vs_disparity.markers + c.error_vs_depth.markers:
        assert np.array_equal(drawn[m.name], [[m.x, m.y]])


def test_save_charts_writes_a_png(tmp_path: Path) -> None:
    out = tmp_path / "charts.png"
    got = save_charts(ARM, out, disparity_px=250, disparity_step_px=0.25, max_disparity_px=256)
    assert got == out
    assert png_size(out) == (1320, 528)  # 11 x 4.4 in at 120 dpi
    assert os.stat(out).st_mode & 0o777 == 0o666 & ~_umask()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["charts.png"]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@pytest.mark.parametrize(("suffix", "magic"), [(".svg", b"<?xml"), (".pdf", b"%PDF")])
def test_save_charts_other_formats(tmp_path: Path, suffix: str, magic: bytes) -> None:
    out = save_charts(ARM, tmp_path / f"c{suffix}", disparity_px=35)
    assert out.read_bytes().startswith(magic)


def test_save_charts_rejects_before_writing(tmp_path: Path) -> None:
    out = tmp_path / "charts.png"
    out.write_bytes(b"keep me")
    with pytest.raises(ValueError, match=r"disparity_px must be finite and >= 0, got -1.0"):
        save_charts(ARM, out, disparity_px=-1)
    with pytest.raises(ValueError, match=r"must end in \.png, \.svg, \.pdf, got '.*charts\.txt'"):
        save_charts(ARM, tmp_path / "charts.txt")
    with pytest.raises(
        ValueError,
        match=r"the chart file's folder must exist: the folder '.*nowhere' does not exist",
    ):
        save_charts(ARM, tmp_path / "nowhere" / "c.png")
    with pytest.raises(TypeError, match=r"path must be a str or os.PathLike, got int 3"):
        save_charts(ARM, 3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"dpi must be an integer from 10 to 1200, got 5000"):
        save_charts(ARM, out, dpi=5000)
    assert out.read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["charts.png"]


def test_failed_write_leaves_the_old_file_and_no_temporary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from matplotlib.figure import Figure

    out = tmp_path / "charts.png"
    out.write_bytes(b"old charts")

    def broken(self: Figure, f: Any, **kwargs: Any) -> None:
        f.write(b"\x89PNG half an image")
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", broken)
    with pytest.raises(OSError, match="disk full"):
        save_charts(ARM, out, disparity_px=250)
    assert out.read_bytes() == b"old charts"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["charts.png"]


def test_overwrite_keeps_the_files_mode(tmp_path: Path) -> None:
    out = tmp_path / "charts.png"
    out.write_bytes(b"old")
    out.chmod(0o640)
    save_charts(ARM, out, disparity_px=250)
    assert png_size(out)[0] > 0
    assert out.stat().st_mode & 0o777 == 0o640


def test_drawing_is_safe_from_threads(tmp_path: Path) -> None:
    from concurrent.futures import ThreadPoolExecutor

    def job(i: int) -> tuple[int, int]:
        return png_size(save_charts(ARM, tmp_path / f"c{i}.png", disparity_px=10 + i, dpi=40))

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with ThreadPoolExecutor(2) as pool:
            sizes = list(pool.map(job, range(4)))
    assert sizes == [(440, 176)] * 4


@pytest.mark.parametrize(
    ("rig", "kwargs"),
    [
        ((100, 700, 0.0), {"max_disparity_px": 1e-20}),
        ((100, 700, 0.0), {"disparity_px": 1e-20}),
        ((100, 700, 0.0), {"max_disparity_px": 1e50}),
        ((100, 700, 0.0), {"disparity_px": 5, "disparity_step_px": 1e-90}),
        ((100, 700, 50.0), {"disparity_px": -10}),
        ((100, 700, -30.0), {"disparity_px": 40, "max_disparity_px": 1e40}),
        # depth flat to a double (B*f/doffs): matplotlib warned of singular limits
        ((1, 1e-40, 1e-60), {"max_disparity_px": 4e-100}),
    ],
)
def test_extreme_values_draw_without_warnings(
    tmp_path: Path, rig: tuple[float, float, float], kwargs: dict[str, Any]
) -> None:
    r = StereoRig.from_pixels(rig[0], rig[1], doffs_px=rig[2])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        save_charts(r, tmp_path / "c.svg", **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"max_disparity_px": 1e-200}, "max_disparity_px 1e-200 cannot be charted"),
        ({"max_disparity_px": 1e300}, "max_disparity_px 1e+300 cannot be charted"),
        ({"disparity_px": 1e-150}, "disparity_px 1e-150 cannot be charted"),
        ({"disparity_px": 1, "disparity_step_px": 1e-200}, "with disparity_step_px 1e-200 cannot"),
    ],
)
def test_save_charts_refuses_what_a_log_axis_cannot_show(
    tmp_path: Path, kwargs: dict[str, Any], message: str
) -> None:
    rig = StereoRig.from_pixels(100, 700)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=re.escape(message)):
            save_charts(rig, tmp_path / "c.svg", **kwargs)
    assert not (tmp_path / "c.svg").exists()
    chart_data(rig, **kwargs)  # the data (the web page's) are still given
