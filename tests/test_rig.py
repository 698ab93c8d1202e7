"""The stereo depth calculator: worked examples, identities, and rejected input."""

from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereodepth import DepthTable, StereoRig

ARM = {"baseline_mm": 150, "focal_mm": 6, "pixel_um": 2.8, "width_px": 1280}
CAR = {"baseline_mm": 250, "focal_mm": 12, "pixel_um": 4.2, "width_px": 2048}


def test_worked_example_bin_picking_arm() -> None:
    rig = StereoRig(**ARM)
    assert rig.disparity_mm(250) == pytest.approx(0.7, rel=1e-12)
    assert rig.depth_m(250) == pytest.approx(1.2857, abs=5e-5)
    assert rig.focal_px == pytest.approx(6 / 0.0028)


def test_worked_example_car() -> None:
    rig = StereoRig(**CAR)
    assert rig.disparity_mm(35) == pytest.approx(0.147, rel=1e-12)
    assert rig.depth_m(35) == pytest.approx(20.408, abs=5e-4)


def test_depth_formula_in_sensor_units() -> None:
    # Z = B * f / (d * p), all lengths in mm.
    rig = StereoRig(**CAR)
    for d in (1.0, 7.5, 35.0, 400.0):
        assert rig.depth_m(d) == pytest.approx(250 * 12 / (d * 4.2e-3) / 1000, rel=1e-12)


def test_max_depth_is_depth_at_one_pixel() -> None:
    rig = StereoRig(**ARM)
    assert rig.max_depth_m == pytest.approx(0.150 * 6 / 0.0028, rel=1e-12)


def test_zero_disparity_is_infinitely_far() -> None:
    rig = StereoRig(**ARM)
    assert rig.depth_m(0) == math.inf
    z = rig.depth_m(np.array([0.0, 1.0]))
    assert z[0] == math.inf and np.isfinite(z[1])


def test_vectorised_and_scalar_agree() -> None:
    rig = StereoRig(**ARM)
    d = np.array([[1.0, 2.0], [250.0, 1000.0]])
    z = rig.depth_m(d)
    assert isinstance(z, np.ndarray) and z.shape == (2, 2)
    assert isinstance(rig.depth_m(2.0), float)
    for (i, j), v in np.ndenumerate(d):
        assert z[i, j] == rig.depth_m(float(v))


def test_depth_resolution_first_order_and_exact() -> None:
    rig = StereoRig(**ARM)
    z = rig.depth_m(250)
    # dZ = Z^2 * p * dd / (B * f), lengths in metres.
    expected = z**2 * 2.8e-6 * 1.0 / (0.150 * 0.006)
    assert rig.depth_resolution_m(z) == pytest.approx(expected, rel=1e-12)
    assert rig.depth_resolution_m(z, 0.25) == pytest.approx(expected / 4, rel=1e-12)
    exact = rig.depth_resolution_m(z, exact=True)
    assert exact == pytest.approx(rig.depth_m(250) - rig.depth_m(251), rel=1e-12)
    assert exact < expected  # the first-order estimate is an upper bound here
    assert exact == pytest.approx(expected, rel=1 / 250 * 1.01)


def test_min_depth_from_search_range_and_fov() -> None:
    rig = StereoRig(**ARM)
    assert rig.min_depth_m(256) == pytest.approx(rig.depth_m(256), rel=1e-12)
    assert rig.hfov_deg == pytest.approx(2 * math.degrees(math.atan(640 / (6 / 0.0028))))
    with pytest.raises(ValueError, match="vfov_deg needs height_px"):
        _ = rig.vfov_deg


def test_required_baseline_inverts_depth_resolution() -> None:
    rig = StereoRig(**CAR)
    b = rig.required_baseline_mm(depth_m=20.0, depth_resolution_m=0.5, disparity_step_px=0.25)
    other = StereoRig(baseline_mm=b, focal_mm=12, pixel_um=4.2)
    assert other.depth_resolution_m(20.0, 0.25) == pytest.approx(0.5, rel=1e-12)


def test_from_pixels_with_doffs() -> None:
    rig = StereoRig.from_pixels(baseline_mm=176.252, focal_px=1038.018, doffs_px=53.271)
    assert rig.depth_m(10.0) == pytest.approx(176.252 * 1038.018 / 63.271 / 1000, rel=1e-12)
    assert rig.disparity_px(rig.depth_m(10.0)) == pytest.approx(10.0, rel=1e-12)
    with pytest.raises(ValueError, match="disparity_mm needs the pixel size"):
        rig.disparity_mm(10)


def test_from_middlebury_calib(tmp_path) -> None:
    p = tmp_path / "calib.txt"
    p.write_text(
        "cam0=[1038.018 0 322.037; 0 1038.018 243.393; 0 0 1]\n"
        "cam1=[1038.018 0 375.308; 0 1038.018 243.393; 0 0 1]\n"
        "doffs=53.271\nbaseline=176.252\nwidth=718\nheight=496\nndisp=73\n"
        "isint=0\nvmin=8\nvmax=65\ndyavg=0\ndymax=0\n"
    )
    rig = StereoRig.from_middlebury_calib(p)
    assert rig.focal_px == 1038.018 and rig.doffs_px == 53.271
    assert rig.baseline_mm == 176.252 and rig.width_px == 718 and rig.height_px == 496


def test_middlebury_calib_errors_name_the_file_and_field(tmp_path) -> None:
    p = tmp_path / "calib.txt"
    p.write_text("cam0=[1 0 0; 0 1 0]\nbaseline=10\n")
    with pytest.raises(ValueError, match=r"calib.txt: cam0 must be a 3x3 matrix"):
        StereoRig.from_middlebury_calib(p)
    p.write_text("cam0=[1 0 0; 0 1 0; 0 0 1]\n")
    with pytest.raises(ValueError, match="missing field 'baseline'"):
        StereoRig.from_middlebury_calib(p)


def test_table_default_and_renderings() -> None:
    rig = StereoRig(**ARM)
    t = rig.table()
    rows = t.to_records()
    assert [r["disparity_px"] for r in rows][:4] == [1, 2, 3, 4]
    assert rows[-1]["disparity_px"] == 256
    for r in rows:
        assert r["depth_m"] == rig.depth_m(r["disparity_px"])
        assert r["depth_resolution_m"] == pytest.approx(rig.depth_resolution_m(r["depth_m"]))
        assert r["disparity_mm"] == pytest.approx(rig.disparity_mm(r["disparity_px"]))
    text = t.to_text().splitlines()
    assert text[0].split() == list(t.columns) and len(text) == len(rows) + 2
    md = t.to_markdown().splitlines()
    assert md[0].startswith("| disparity_px |") and md[1].startswith("|---:")
    small = StereoRig(baseline_mm=100, focal_mm=4, pixel_um=3, width_px=40).table()
    assert max(r["disparity_px"] for r in small) <= 39


def test_table_subpixel_column_and_custom_disparities() -> None:
    rig = StereoRig(**ARM)
    t = rig.table([0, 10, 250], disparity_step_px=0.25)
    assert "depth_resolution_subpx_m" in t.columns
    r0, r1, _ = t.to_records()
    assert r0["depth_m"] == math.inf and r0["depth_resolution_m"] == math.inf
    assert r1["depth_resolution_subpx_m"] == pytest.approx(r1["depth_resolution_m"] / 4)


def test_summary_has_every_result_and_is_json_ready() -> None:
    import json

    rig = StereoRig(**ARM)
    s = rig.summary(250, disparity_step_px=0.1, max_disparity_px=256)
    for key in (
        "depth_m",
        "disparity_mm",
        "max_depth_m",
        "depth_resolution_m",
        "focal_px",
        "hfov_deg",
        "table",
        "min_depth_m",
        "depth_resolution_subpx_m",
    ):
        assert s[key] is not None, key
    assert s["depth_m"] == rig.depth_m(250)
    json.dumps(s, allow_nan=False)
    s0 = rig.summary(0)
    assert s0["depth_m"] is None and s0["depth_resolution_m"] is None  # infinite -> None


@settings(max_examples=80, deadline=None)
@given(st.floats(1e-3, 1e4), st.floats(0.1, 5000), st.floats(0.1, 100), st.floats(0.5, 20))
def test_depth_disparity_round_trip(d: float, b: float, f: float, p: float) -> None:
    rig = StereoRig(baseline_mm=b, focal_mm=f, pixel_um=p)
    assert rig.disparity_px(rig.depth_m(d)) == pytest.approx(d, rel=1e-9)


@settings(max_examples=80, deadline=None)
@given(st.lists(st.just(0.0) | st.floats(1e-300, 1e5), min_size=2, max_size=30))
def test_depth_decreases_with_disparity(ds: list[float]) -> None:
    # (A disparity below B*f / 1.8e308 px, 5e-324 say, overflows the depth: ValueError.)
    rig = StereoRig(**CAR)
    z = rig.depth_m(np.sort(np.array(ds)))
    assert np.all(np.diff(z[np.isfinite(z)]) <= 0)


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({**ARM, "baseline_mm": 0}, ValueError, "baseline_mm must be a finite number > 0, got 0"),
        ({**ARM, "baseline_mm": -150}, ValueError, "baseline_mm .* got -150"),
        ({**ARM, "focal_mm": float("nan")}, ValueError, "focal_mm .* got nan"),
        ({**ARM, "pixel_um": float("inf")}, ValueError, "pixel_um .* got inf"),
        ({**ARM, "pixel_um": "2.8"}, TypeError, "pixel_um must be a real number, got str"),
        ({**ARM, "width_px": 0}, ValueError, "width_px must be an integer >= 1, got 0"),
        ({**ARM, "width_px": 12.5}, TypeError, "width_px must be an integer, got float"),
        ({**ARM, "height_px": -3}, ValueError, "height_px must be an integer >= 1, got -3"),
        ({**ARM, "width_px": 10**30}, ValueError, "width_px must be an integer <= 16777216"),
        ({**ARM, "focal_mm": 1e-300, "pixel_um": 1e20}, ValueError, "focal length of 1e-317 px"),
        ({**ARM, "focal_mm": 1e300, "pixel_um": 1e-20}, ValueError, "focal length of inf px"),
        (
            {**ARM, "baseline_mm": 1e-300, "focal_mm": 1e-12},
            ValueError,
            "B\\*f = 3.57.*e-313 m\\*px, outside",
        ),
    ],
)
def test_rejected_rig(kwargs, exc, match) -> None:
    with pytest.raises(exc, match=match):
        StereoRig(**kwargs)


@pytest.mark.parametrize(
    ("call", "exc", "match"),
    [
        (lambda r: r.depth_m(-1), ValueError, "disparity_px must be finite and >= 0, got -1.0"),
        (lambda r: r.depth_m(float("nan")), ValueError, "disparity_px .* got nan"),
        (lambda r: r.depth_m(np.array([1.0, -2.0])), ValueError, "got -2.0"),
        (lambda r: r.depth_m("1"), TypeError, "disparity_px must be a real number or array"),
        (lambda r: r.depth_m(None), TypeError, "disparity_px must be a real number or array"),
        (lambda r: r.disparity_px(0), ValueError, "depth_m must be > 0, got 0.0"),
        (lambda r: r.depth_resolution_m(1.0, 0), ValueError, "disparity_step_px .* got 0"),
        (lambda r: r.depth_resolution_m(-1.0), ValueError, "depth_m must be > 0, got -1.0"),
        (lambda r: r.depth_resolution_m(1.0, exact=1), TypeError, "exact must be a bool"),
        (lambda r: r.min_depth_m(0), ValueError, "max_disparity_px must be a finite number > 0"),
        (
            lambda r: StereoRig.from_pixels(100, 700, doffs_px=-5).min_depth_m(3),
            ValueError,
            r"max_disparity_px must be finite and >= 5 \(with doffs_px -5, a disparity below 5 px "
            r"puts the point behind the cameras\), got 3.0",
        ),
        (lambda r: r.required_baseline_mm(10, 0), ValueError, "depth_resolution_m .* got 0"),
        (lambda r: r.table([]), ValueError, "disparities_px must be a non-empty 1-D sequence"),
        (lambda r: r.table([1, -1]), ValueError, "disparities_px must be finite and >= 0"),
        (lambda r: r.summary("x"), TypeError, "disparity_px must be a real number, got str"),
        (
            lambda r: r.summary(10**400),
            ValueError,
            "disparity_px must be within the range of a double",
        ),
        (lambda r: r.min_depth_m(2**1024), ValueError, "max_disparity_px must be within the"),
    ],
)
def test_rejected_questions(call, exc, match) -> None:
    with pytest.raises(exc, match=match):
        call(StereoRig(**ARM))


def test_hfov_needs_width() -> None:
    with pytest.raises(ValueError, match="hfov_deg needs width_px, got None"):
        _ = StereoRig(baseline_mm=1, focal_mm=1, pixel_um=1).hfov_deg


@pytest.mark.parametrize("doffs", [-0.5, -1.0, -5.0, -300.5])
def test_negative_doffs_moves_infinity(doffs: float) -> None:
    # With d + doffs <= 0 at 1 px, a whole-pixel matcher already reaches infinity.
    rig = StereoRig.from_pixels(100, 700, width_px=640, doffs_px=doffs)
    assert rig.max_depth_m == (math.inf if doffs <= -1 else 70.0 / (1 + doffs))
    rows = rig.table().to_records()
    assert rows[0]["disparity_px"] >= -doffs
    assert rows[0]["disparity_px"] < -doffs + 2 or rows[0]["disparity_px"] in (1.0, 6.0)
    summary = rig.summary(400, max_disparity_px=500)
    assert summary["max_depth_m"] == (None if doffs <= -1 else rig.max_depth_m)
    assert summary["depth_m"] == pytest.approx(70.0 / (400 + doffs))


def test_positive_doffs_puts_far_points_at_negative_disparities() -> None:
    # Middlebury's Adirondack (doffs 53.271 px): infinity is at d = -53.271 px, and every
    # point beyond B*f / doffs = 3.43 m has a negative disparity. disparity_px() gives such
    # disparities and the map kernels (depth_map, disparity_to_depth) take them; depth_m
    # refused them ("must be finite and >= 0"), so depth_m(disparity_px(z)) failed.
    rig = StereoRig.from_pixels(176.252, 1038.018, doffs_px=53.271)
    bf = 0.176252 * 1038.018
    for z in (5.0, 100.0, 1e4):
        d = rig.disparity_px(z)
        assert d < 0
        assert rig.depth_m(d) == pytest.approx(z, rel=1e-12)
    d = np.array([[-53.0, -20.0, -1.0, 0.0, 10.0]], dtype=np.float32)
    np.testing.assert_allclose(rig.depth_m(d), rig.depth_map(d), rtol=1e-6)
    assert rig.depth_m(-20.0) == pytest.approx(bf / 33.271, rel=1e-12)
    assert rig.depth_m(-53.271) == math.inf  # the point at infinity
    assert rig.table([-20.0]).to_records()[0]["depth_m"] == rig.depth_m(-20.0)
    with pytest.raises(
        ValueError,
        match=r"disparity_px must be finite and >= -53.271 \(with doffs_px 53.271, a disparity "
        r"of -53.271 px is a point at infinity and one below it lies behind the cameras\), "
        r"got -54.0",
    ):
        rig.depth_m(-54.0)
    # Without doffs the rule and its message are as before.
    with pytest.raises(ValueError, match=r"^disparity_px must be finite and >= 0, got -1.0$"):
        StereoRig.from_pixels(176.252, 1038.018).depth_m(-1.0)


_EXTREME = st.sampled_from([1e-300, 1e-150, 1e-12, 1e-3, 1.0, 1e3, 1e12, 1e150, 1e300])


@settings(max_examples=150, deadline=None)
@given(_EXTREME, _EXTREME, _EXTREME, st.sampled_from([0.0, 1e-300, 0.5, 1.0, 1e300]))
def test_extreme_numbers_answer_or_raise_value_error(b: float, f: float, p: float, d: float):
    """Far outside any real rig, every answer is a number, inf or None, never a warning (the
    suite turns warnings into errors) or a ZeroDivisionError; a rig whose focal length or
    B*f leaves the range of a double is refused at construction."""
    focal_px = f / (p / 1000.0)
    if not (
        sys.float_info.min <= focal_px < math.inf
        and sys.float_info.min <= b / 1000.0 * focal_px < math.inf
    ):
        with pytest.raises(ValueError, match="outside the range of a double"):
            StereoRig(b, f, p, width_px=1 << 24, height_px=1)
        return
    rig = StereoRig(b, f, p, width_px=1 << 24, height_px=1)
    # A result the model makes finite but a double cannot hold is a ValueError naming the
    # parameter that leads there, never a silent inf or 0 (null in JSON).
    overflow = "that a double can hold"
    results: list[Any] = []
    for call in (
        lambda: rig.summary(d, disparity_step_px=0.25, max_disparity_px=256),
        lambda: rig.table(disparity_step_px=0.5).to_text(),
        lambda: rig.required_baseline_mm(1e300, 1e-300),
    ):
        try:
            results.append(call())
        except ValueError as exc:
            results.append(exc)
    summary, _, baseline = results
    if isinstance(summary, ValueError):
        assert overflow in str(summary)
    else:
        assert summary["focal_px"] > 0
        for row in summary["table"]:
            assert all(v is None or 0 < v < math.inf for v in row.values())
        if d > 0:
            assert summary["depth_m"] is not None and summary["depth_m"] > 0
    assert not isinstance(results[1], ValueError) or overflow in str(results[1])
    if isinstance(baseline, ValueError):
        assert str(baseline).startswith("depth_m must give a baseline that a double can hold")
    else:
        assert 0 < baseline < math.inf


def test_results_beyond_a_double_raise_naming_the_parameter() -> None:
    # They were inf (a finite depth, null in JSON) or 0 (a positive depth resolution).
    huge = StereoRig.from_pixels(1e300, 1e5)  # B*f = 1e302 m*px
    with pytest.raises(ValueError, match=r"^disparity_px must give a depth .* got 1e-300, "):
        huge.depth_m(1e-300)
    with pytest.raises(ValueError, match=r"^disparity_px .* got 1e-300, which gives inf m"):
        huge.depth_m(np.array([1.0, 1e-300]))
    with pytest.raises(ValueError, match=r"^disparity_px .* got 1e-300"):
        huge.summary(1e-300)
    with pytest.raises(ValueError, match=r"^depth_m must give a disparity .* got 1e-300"):
        huge.disparity_px(1e-300)
    with pytest.raises(ValueError, match=r"^depth_m must give a depth resolution .* got 1e\+306"):
        huge.depth_resolution_m(1e306)  # 1e306 * 1e306 / 1e302 = 1e310 m
    with pytest.raises(ValueError, match=r"^max_disparity_px must give a depth .* got 1e-300"):
        huge.min_depth_m(1e-300)
    with pytest.raises(ValueError, match=r"^disparities_px must give a depth .* got 1e-300"):
        huge.table([1.0, 1e-300])
    small = StereoRig.from_pixels(100, 1000)  # B*f = 100 m*px
    with pytest.raises(ValueError, match=r"^disparity_px .* got 1e\+300, which gives 0.0 m"):
        small.summary(1e300)  # depth 1e-298 m, resolution 1e-596 m: 0
    sensor = StereoRig(baseline_mm=1, focal_mm=1e300, pixel_um=1e300)  # a pixel of 1e297 mm
    with pytest.raises(ValueError, match=r"^disparity_px must give a disparity on the sensor"):
        sensor.disparity_mm(1e300)
    # A step that makes a resolution leave the range names the step, not the depth.
    with pytest.raises(ValueError, match=r"^disparity_step_px must give .* got 1e\+308, "):
        small.depth_resolution_m(100.0, 1e308)
    with pytest.raises(ValueError, match=r"^disparity_step_px must give .* got 5e-324, "):
        small.summary(16.0, disparity_step_px=5e-324, table_disparities_px=[1.0])
    # The true infinities stay inf: a point at infinity and its resolution.
    assert huge.depth_m(0.0) == math.inf
    assert huge.depth_resolution_m(math.inf) == math.inf
    assert huge.summary(0.0)["depth_m"] is None


def test_no_spurious_overflow_where_the_result_fits() -> None:
    # By hand: B*f = 1e302 m*px; d = 1 px: Z = 1e302 m, dZ = Z**2 / (B*f) = 1e302 m and the
    # exact Z(1) - Z(2) = 5e301 m. Z * Z overflowed first.
    huge = StereoRig.from_pixels(1e300, 1e5)
    assert huge.depth_resolution_m(1e302) == pytest.approx(1e302, rel=1e-12)
    assert huge.depth_resolution_m(1e302, exact=True) == pytest.approx(5e301, rel=1e-12)
    assert huge.table([1.0]).rows[0][-1] == pytest.approx(1e302, rel=1e-12)
    # The exact difference cancelled to 0 at large disparities: at d = 1e17 px with B*f =
    # 100 m*px it is B*f / (d (d + 1)) = 1e-32 m.
    small = StereoRig.from_pixels(100, 1000)
    z = small.depth_m(1e17)
    assert small.depth_resolution_m(z, exact=True) == pytest.approx(1e-32, rel=1e-12)
    # B = Z**2 dd / (dZ f) = 1e400 / (1e-10 * 1e300) m * 1000 = 1e113 mm; Z * Z overflowed.
    rig = StereoRig.from_pixels(1e-5, 1e300)
    assert rig.required_baseline_mm(1e200, 1e-10) == pytest.approx(1e113, rel=1e-9)


def test_rigs_compare_by_value() -> None:
    # Two rigs built from the same values are equal (a set or dict key works); the repr,
    # eval'd, gives an equal rig; any value that differs makes them unequal.
    a = StereoRig(baseline_mm=120, focal_mm=4, pixel_um=2, width_px=640, height_px=480)
    b = StereoRig(baseline_mm=120.0, focal_mm=4.0, pixel_um=2.0, width_px=640, height_px=480)
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
    assert eval(repr(a), {"StereoRig": StereoRig}) == a
    p = StereoRig.from_pixels(baseline_mm=120, focal_px=2000, doffs_px=3.5, width_px=640)
    assert eval(repr(p), {"StereoRig": StereoRig}) == p
    assert p != StereoRig.from_pixels(baseline_mm=120, focal_px=2000, width_px=640)
    assert a != StereoRig(baseline_mm=120, focal_mm=4, pixel_um=2, width_px=640)
    assert a != StereoRig(baseline_mm=121, focal_mm=4, pixel_um=2, width_px=640, height_px=480)
    assert a != StereoRig.from_pixels(baseline_mm=120, focal_px=2000, width_px=640, height_px=480)
    assert a != "a rig" and a != (120, 4, 2)


@pytest.mark.parametrize(
    ("columns", "rows", "error", "message"),
    [
        (("a",), ((1.0, 2.0),), ValueError, r"rows\[0\] must be a tuple of 1 numbers"),
        (("a", "b"), 5, TypeError, r"rows must be a tuple of rows .*got int 5"),
        (("a", "b"), ((1.0, "x"),), TypeError, r"rows\[0\]\[1\] must be a real number"),
        ("ab", (), TypeError, r"columns must be a tuple of str, got str 'ab'"),
        ((1, 2), (), TypeError, r"columns must be a tuple of str, got \(1, 2\)"),
    ],
)
def test_depth_table_checks_its_cells(
    columns: Any, rows: Any, error: type[Exception], message: str
) -> None:
    # A row longer than the columns lost its last cells from the text, silently; rows=5 was
    # "'int' object is not iterable", naming nothing.
    with pytest.raises(error, match=message):
        DepthTable(columns=columns, rows=rows)


def test_depth_table_keeps_tuples_of_floats() -> None:
    t = DepthTable(columns=["d", "z"], rows=[[1, 2.5], (np.float32(3), 4)])
    assert t.columns == ("d", "z")
    assert t.rows == ((1.0, 2.5), (3.0, 4.0))
    assert all(type(v) is float for r in t.rows for v in r)
    assert list(t) == [{"d": 1.0, "z": 2.5}, {"d": 3.0, "z": 4.0}]


def test_python_ints_beyond_int64_are_numbers() -> None:
    # numpy keeps a Python int beyond int64 as an object: depth_m(10**20), a disparity a
    # double holds, was "TypeError: disparity_px must be a real number or array, got int with
    # dtype object" (StereoRig(baseline_mm=10**20, ...) and summary(10**20) took it), and one
    # beyond a double (10**400) was that TypeError, not summary's ValueError naming the range.
    rig = StereoRig(**ARM)
    bf = rig.depth_m(1.0)  # B*f in m*px
    assert rig.depth_m(10**20) == pytest.approx(bf / 1e20, rel=1e-15)
    assert rig.depth_m(2**64) == rig.depth_m(float(2**64))
    np.testing.assert_array_equal(rig.depth_m([2**64, 4]), rig.depth_m([float(2**64), 4.0]))
    assert rig.depth_resolution_m(10**20) == rig.depth_resolution_m(1e20)
    assert rig.table([10**20, 2]).rows == rig.table([1e20, 2.0]).rows
    for call, name in (
        (lambda: rig.depth_m(10**400), "disparity_px"),
        (lambda: rig.depth_m([1, -(10**400)]), "disparity_px"),
        (lambda: rig.disparity_px(10**400), "depth_m"),
        (lambda: rig.table([10**400]), "disparities_px"),
    ):
        with pytest.raises(ValueError, match=rf"^{name} must be within the range of a double"):
            call()
    with pytest.raises(TypeError, match="disparity_px must be a real number or array"):
        rig.depth_m([2**64, "1"])  # an object array of other things stays a TypeError
