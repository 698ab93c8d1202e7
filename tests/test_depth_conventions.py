"""One reading of a disparity array across the library: OpenCV's int16 x16 and KITTI's uint16
x256 where a map is expected, pixels where a number is, the rig's image size where it has
one, and OpenCV's fixed point rounded exactly."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

import stereodepth as sd

RIG = {"focal_px": 700.0, "baseline_m": 0.12}


def exact_sixteenths(x: float) -> int:
    """x * 16 rounded half away from zero, in exact arithmetic."""
    q = Fraction(x) * 16
    whole = int(q)  # toward zero
    return whole + (1 if q - whole >= Fraction(1, 2) else -1 if whole - q >= Fraction(1, 2) else 0)


def test_to_opencv_disparity_rounds_exactly_half_away_from_zero() -> None:
    below_half = float(np.nextafter(0.5, 0)) / 16  # 0.0312499... px: 0 sixteenths, not 1
    values = [below_half, -below_half, 0.5 / 16, -0.5 / 16, 1.5 / 16, -1.5 / 16, 2047.9]
    rng = np.random.default_rng(3)
    values += list(rng.uniform(-60, 2000, 500))
    # Values next to a half sixteenth, where adding 0.5 first rounds the sum.
    halves = (np.arange(-900, 30000) + 0.5) / 16
    values += list(np.nextafter(halves, -np.inf)) + list(np.nextafter(halves, np.inf))
    d = np.array([values], dtype=np.float64)
    got = sd.to_opencv_disparity(d, min_disparity=-60)
    want = [exact_sixteenths(v) for v in values]
    assert got.dtype == np.int16
    assert got[0].tolist() == want


def test_to_opencv_disparity_float32_input_rounds_the_same() -> None:
    d32 = (np.arange(-800, 800, dtype=np.float32) / np.float32(37)).reshape(40, 40)
    want = [exact_sixteenths(float(v)) for v in d32.ravel()]
    assert sd.to_opencv_disparity(d32, min_disparity=-30).ravel().tolist() == want


@pytest.mark.parametrize("dtype", [np.int16, np.uint16])
def test_depth_m_refuses_the_fixed_point_dtypes(dtype: type) -> None:
    # The same int16 array gave 0.525 m here (read as pixels) and 8.4 m from depth_map
    # (OpenCV's x16): depth_m takes pixels only, and says how to convert.
    rig = sd.StereoRig.from_pixels(baseline_mm=120, focal_px=700)
    raw = np.array([[160]], dtype)
    for value in (raw, raw[0, 0]):
        with pytest.raises(TypeError, match=r"disparity_px must be in pixels.*"):
            rig.depth_m(value)
    with pytest.raises(TypeError, match="disparity_px must be in pixels"):
        sd.StereoRig(baseline_mm=120, focal_mm=6, pixel_um=3).disparity_mm(raw)
    assert rig.depth_m(np.array([160], np.int64))[0] == pytest.approx(0.525)
    assert rig.depth_m(np.array([160], np.int32))[0] == pytest.approx(0.525)
    assert rig.depth_map(np.array([[160]], np.int16))[0, 0] == pytest.approx(8.4)


@pytest.mark.parametrize("min_disparity", [3000, 2048, -2048, -100000])
def test_opencv_int16_min_disparity_outside_its_range_is_refused(min_disparity: int) -> None:
    raw = np.full((3, 4), 160, np.int16)
    calls = [
        lambda: sd.disparity_to_depth(raw, min_disparity=min_disparity, **RIG),
        lambda: sd.reproject(raw, cx_px=1.0, cy_px=1.0, min_disparity=min_disparity, **RIG),
        lambda: sd.from_opencv_disparity(raw, min_disparity=min_disparity),
        lambda: sd.StereoRig.from_pixels(baseline_mm=120, focal_px=700).depth_map(
            raw, min_disparity=min_disparity
        ),
    ]
    for call in calls:
        with pytest.raises(ValueError, match=r"min_disparity must be in \[-2047, 2047\]"):
            call()


def test_opencv_int16_min_disparity_at_its_limits_is_read() -> None:
    raw = np.array([[32752, 16, -32752, -32768]], np.int16)
    hi = sd.disparity_to_depth(raw, min_disparity=2047, **RIG)
    np.testing.assert_allclose(hi[0, 0], 700.0 * 0.12 / 2047.0, rtol=1e-6)  # 32752 / 16
    assert np.isnan(hi[0, 1:]).all()  # below 2047 px: holes, as OpenCV means
    np.testing.assert_array_equal(
        sd.from_opencv_disparity(raw, min_disparity=2047), [[2047.0, np.nan, np.nan, np.nan]]
    )
    lo = sd.disparity_to_depth(raw, min_disparity=-2047, doffs_px=3000.0, **RIG)
    z = 700.0 * 0.12 / (np.array([2047.0, 1.0, -2047.0]) + 3000.0)
    np.testing.assert_allclose(lo[0, :3], z, rtol=1e-6)
    assert np.isnan(lo[0, 3])  # (min_disparity - 1) * 16: OpenCV's hole


def test_a_min_disparity_that_makes_every_raw_value_a_hole_is_refused() -> None:
    kitti = np.full((2, 2), 256 * 40, np.uint16)
    with pytest.raises(ValueError, match=r"min_disparity / scale must be at most 65535"):
        sd.disparity_to_depth(kitti, scale=1 / 256, min_disparity=256, **RIG)
    out = sd.disparity_to_depth(kitti, scale=1 / 256, min_disparity=40, **RIG)
    np.testing.assert_allclose(out, 700.0 * 0.12 / 40.0, rtol=1e-6)
    custom = np.full((2, 2), 100, np.int16)
    with pytest.raises(ValueError, match=r"at most 32767"):
        sd.disparity_to_depth(custom, scale=0.5, min_disparity=20000, **RIG)


def test_depth_map_refuses_a_map_of_another_size_than_the_rigs() -> None:
    rig = sd.StereoRig.from_pixels(baseline_mm=120, focal_px=700, width_px=80, height_px=100)
    good = np.full((100, 80), 50, np.float32)
    np.testing.assert_allclose(rig.depth_map(good), 700 * 0.12 / 50, rtol=1e-6)
    np.testing.assert_allclose(rig.depth_map(good[None]), 700 * 0.12 / 50, rtol=1e-6)
    for bad in (good[:, :40], good[:50], good.T, np.stack([good.T, good.T])):
        with pytest.raises(ValueError, match=r"disparity must have the rig's image size, 80 x 100"):
            rig.depth_map(bad)
    only_width = sd.StereoRig.from_pixels(baseline_mm=120, focal_px=700, width_px=80)
    only_width.depth_map(np.ones((7, 80), np.float32))
    with pytest.raises(ValueError, match=r"80 x any px.*got 81 x 7 px"):
        only_width.depth_map(np.ones((7, 81), np.float32))
    # A rig without an image size takes any map.
    sd.StereoRig.from_pixels(baseline_mm=120, focal_px=700).depth_map(good[:3, :5])


def test_depth_map_of_a_sized_rig_names_a_ragged_list() -> None:
    # The size check read the map's shape with np.shape, which gave numpy's own "inhomogeneous
    # shape" message for a ragged list; a rig without a size named the parameter.
    for rig in (
        sd.StereoRig.from_pixels(baseline_mm=100, focal_px=500, width_px=3, height_px=2),
        sd.StereoRig.from_pixels(baseline_mm=100, focal_px=500),
    ):
        with pytest.raises(ValueError, match=r"^disparity must be a rectangular array"):
            rig.depth_map([[1, 2], [3]])


def test_holes_are_the_same_in_float32_depth_uint16_depth_and_points() -> None:
    # A float32 map whose holes are float32(0.1): invalid_value=0.1 made them holes in float32
    # depth and in reproject, but 100 m (65535 mm) in uint16 depth, which compared in float64.
    d32 = np.array([[0.1, 2.0, 0.1, 7.5]], dtype=np.float32)
    # uint16 at a scale whose min_disparity / scale rounds up in float64 (21 / 0.35 is
    # 60.00000000000001): raw 60 is 21 px, min_disparity itself, kept by float32 depth and
    # reproject, a hole in uint16 depth.
    u16 = np.array([[60, 59, 61, 100]], dtype=np.uint16)
    for d, kw in (
        (d32, {"invalid_value": 0.1}),
        (d32.astype(np.int16), {"invalid_value": 0.1, "scale": 1.0}),
        (u16, {"scale": 0.35, "min_disparity": 21}),
    ):
        z32 = sd.disparity_to_depth(d, **RIG, **kw)
        z16 = sd.disparity_to_depth(d, **RIG, **kw, dtype=np.uint16)
        xyz = sd.reproject(d, **RIG, **kw)
        holes = np.isnan(z32)
        assert holes.any() and not holes.all()
        assert np.array_equal(z16 == 0, holes), (d.dtype, kw)
        assert np.array_equal(np.isnan(xyz[..., 2]), holes), (d.dtype, kw)
