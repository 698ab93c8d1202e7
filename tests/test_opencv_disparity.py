"""OpenCV's int16 disparities: holes are the raw values below min_disparity * 16.

OpenCV's StereoBM and StereoSGBM write holes as (minDisparity - 1) * 16, so the hole marker is
positive for minDisparity > 1 and valid disparities are negative for minDisparity < 0. Every
function that reads the int16 format takes the matcher's min_disparity (default 0).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import reference
from stereodepth.io import read_image
from stereodepth.metrics import evaluate

MIN_DISPARITIES = [-16, 0, 16, 32]
FOCAL_PX, BASELINE_M = 700.0, 0.12


def assert_same(got: np.ndarray, want: np.ndarray) -> None:
    np.testing.assert_array_equal(got, want, strict=True)


def float_map(rng: np.random.Generator, m: int, shape: tuple[int, int]) -> np.ndarray:
    """Disparities in [m, m + 64) on sixteenths (exact in OpenCV's format), a fifth holes."""
    d = (m + rng.integers(0, 64 * 16, size=shape) / 16).astype(np.float32)
    d[rng.random(shape) < 0.2] = np.nan
    return d


def rig(m: int) -> dict[str, float]:
    """doffs_px > 0 keeps d + doffs > 0 over [m, m + 64) for negative m."""
    return {"focal_px": FOCAL_PX, "baseline_m": BASELINE_M, "doffs_px": max(0.0, 8.0 - m)}


@pytest.mark.parametrize("m", MIN_DISPARITIES)
@pytest.mark.parametrize("dtype", [np.float32, np.uint16])
def test_round_trip_through_opencv_format_equals_the_float_map(m: int, dtype: Any) -> None:
    rng = np.random.default_rng(100 + m)
    d = float_map(rng, m, (37, 53))
    raw = stereodepth.to_opencv_disparity(d, min_disparity=m)
    assert ((raw == (m - 1) * 16) == np.isnan(d)).all()
    want = stereodepth.disparity_to_depth(d, dtype=dtype, **rig(m))
    got = stereodepth.disparity_to_depth(raw, dtype=dtype, min_disparity=m, **rig(m))
    assert_same(got, want)
    assert_same(reference.disparity_to_depth(raw, dtype=dtype, min_disparity=m, **rig(m)), want)
    # every pixel the float map has is kept, every hole stays a hole
    valid = np.isnan(want) if dtype == np.float32 else want == 0
    assert (valid == np.isnan(d)).all()


@pytest.mark.parametrize("m", MIN_DISPARITIES)
def test_round_trip_through_reproject_and_the_decoder(m: int) -> None:
    rng = np.random.default_rng(200 + m)
    d = float_map(rng, m, (2, 19, 41))
    raw = stereodepth.to_opencv_disparity(d, min_disparity=m)
    assert_same(stereodepth.from_opencv_disparity(raw, min_disparity=m), d)
    want = stereodepth.reproject(d, **rig(m))
    got = stereodepth.reproject(raw, min_disparity=m, **rig(m))
    assert_same(got, want)
    assert_same(reference.reproject(raw, min_disparity=m, **rig(m)), want)
    assert (np.isnan(got[..., 2]) == np.isnan(d)).all()


def test_positive_hole_marker_is_a_hole() -> None:
    """minDisparity=16: holes are +240, which once became a depth of f*B/15."""
    raw = np.array([[240, 256, 16 * 20, 255, -16]], np.int16)
    z = stereodepth.disparity_to_depth(
        raw, focal_px=FOCAL_PX, baseline_m=BASELINE_M, min_disparity=16
    )
    k = FOCAL_PX * BASELINE_M
    np.testing.assert_allclose(z[0, 1:3], [k / 16, k / 20], rtol=1e-6)
    assert np.isnan(z[0, [0, 3, 4]]).all()
    p = stereodepth.reproject(raw, focal_px=FOCAL_PX, baseline_m=BASELINE_M, min_disparity=16)
    assert np.isnan(p[0, [0, 3, 4]]).all() and np.isfinite(p[0, 1:3]).all()


def test_negative_disparity_is_valid_with_a_principal_point_offset() -> None:
    """minDisparity=-16: d = -5 px is stored as -80 and is finite with doffs_px > 0."""
    raw = np.array([[-80, -256, -272, 0]], np.int16)
    kw = {"focal_px": FOCAL_PX, "baseline_m": BASELINE_M, "doffs_px": 20.0, "min_disparity": -16}
    z = stereodepth.disparity_to_depth(raw, **kw)
    k = FOCAL_PX * BASELINE_M
    np.testing.assert_allclose(z[0, [0, 1, 3]], [k / 15, k / 4, k / 20], rtol=1e-6)
    assert np.isnan(z[0, 2])  # (-16 - 1) * 16 = -272, OpenCV's hole
    p = stereodepth.reproject(raw, **kw)
    np.testing.assert_allclose(p[0, [0, 1, 3], 2], z[0, [0, 1, 3]], rtol=1e-6)
    assert np.isnan(p[0, 2]).all()


def test_default_is_opencvs_default_min_disparity_zero() -> None:
    raw = np.array([[-16, -1, 0, 16]], np.int16)
    z = stereodepth.disparity_to_depth(raw, focal_px=1.0, baseline_m=1.0, doffs_px=1.0)
    assert np.isnan(z[0, :2]).all() and np.isfinite(z[0, 2:]).all()
    d = stereodepth.from_opencv_disparity(raw)
    assert np.isnan(d[0, :2]).all() and (d[0, 2:] == [0.0, 1.0]).all()


def test_min_disparity_on_float_input_is_a_lower_limit_in_pixels() -> None:
    d = np.array([[-3.0, -2.0, 4.0, np.nan]], np.float32)
    z = stereodepth.disparity_to_depth(
        d, focal_px=1.0, baseline_m=1.0, doffs_px=10.0, min_disparity=-2
    )
    assert np.isnan(z[0, [0, 3]]).all() and np.isfinite(z[0, 1:3]).all()
    z = stereodepth.disparity_to_depth(d, focal_px=1.0, baseline_m=1.0, doffs_px=10.0)
    assert np.isfinite(z[0, :3]).all()  # no lower limit unless given


def test_metrics_read_opencv_output_with_its_min_disparity() -> None:
    gt = np.full((1, 4), 20.0)
    raw = np.array([[240, 16 * 20, 16 * 21, 16 * 23]], np.int16)
    m = evaluate(raw, gt, min_disparity=16)
    assert m.estimated == 3 and m.bad_2 == pytest.approx(0.5)
    want = evaluate(stereodepth.from_opencv_disparity(raw, min_disparity=16), gt)
    assert m == want
    assert evaluate(raw, gt, min_disparity=0).estimated == 4  # minDisparity 0: 240 is 15 px
    with pytest.raises(TypeError, match="pass the matcher's minDisparity as min_disparity"):
        evaluate(raw, gt)  # no guess at the hole marker


@pytest.mark.parametrize(
    ("call", "exc", "message"),
    [
        (
            lambda: stereodepth.from_opencv_disparity(np.zeros((2, 2), np.float32)),
            TypeError,
            "raw must be OpenCV's int16 disparity",
        ),
        (
            lambda: stereodepth.from_opencv_disparity(
                np.zeros((2, 2), np.int16), min_disparity=1.5
            ),
            TypeError,
            "min_disparity must be an integer, got float 1.5",
        ),
        # Out of OpenCV's range every pixel silently became NaN; to_opencv_disparity refused.
        (
            lambda: stereodepth.from_opencv_disparity(
                np.zeros((2, 2), np.int16), min_disparity=1_000_000
            ),
            ValueError,
            r"min_disparity must be in \[-2047, 2047\] .* got 1000000",
        ),
        (
            lambda: stereodepth.from_opencv_disparity(
                np.zeros((2, 2), np.int16), min_disparity=-2048
            ),
            ValueError,
            r"min_disparity must be in \[-2047, 2047\] .* got -2048",
        ),
        (
            lambda: stereodepth.disparity_to_depth(
                np.zeros((2, 2), np.int16), focal_px=1.0, baseline_m=1.0, min_disparity="16"
            ),
            TypeError,
            "min_disparity must be an integer, got str '16'",
        ),
        (
            lambda: stereodepth.reproject(
                np.zeros((2, 2), np.int16), focal_px=1.0, baseline_m=1.0, min_disparity=2.0
            ),
            TypeError,
            "min_disparity must be an integer, got float 2.0",
        ),
        (
            lambda: stereodepth.disparity_to_depth(
                np.zeros((2, 2), np.float32), focal_px=1.0, baseline_m=1.0, min_disparity=10**40
            ),
            ValueError,
            "min_disparity must be an integer <= 16777216, got 1" + "0" * 40,
        ),
        (
            lambda: evaluate(np.zeros((2, 2), np.int16), np.zeros((2, 2)), min_disparity=True),
            TypeError,
            "min_disparity must be an integer, got bool True",
        ),
    ],
)
def test_bad_min_disparity_is_rejected(call: Any, exc: type, message: str) -> None:
    with pytest.raises(exc, match=message.replace("(", r"\(")):
        call()


@pytest.mark.parametrize(
    ("raw", "exc", "message"),
    [
        # A 0-d one failed inside: "'numpy.float32' object does not support item assignment".
        (np.int16(16), ValueError, r"raw must have shape \(H, W\) or \(N, H, W\), got \(\)"),
        (np.zeros(4, np.int16), ValueError, r"raw must have shape .* got \(4,\)"),
        (np.zeros((1, 1, 2, 2), np.int16), ValueError, r"got \(1, 1, 2, 2\)"),
        ([[16, 32], [48]], ValueError, r"raw must be a rectangular array .* got list"),
    ],
)
def test_bad_raw_shape_is_rejected(raw: Any, exc: type, message: str) -> None:
    with pytest.raises(exc, match=message):
        stereodepth.from_opencv_disparity(raw)


def test_stack_of_raw_maps_is_decoded_frame_by_frame() -> None:
    raw = np.array([[[16, -16]], [[40, 0]]], np.int16)  # by hand: 1, hole; 2.5, 0
    d = stereodepth.from_opencv_disparity(raw)
    np.testing.assert_array_equal(d, np.array([[[1.0, np.nan]], [[2.5, 0.0]]], np.float32))


def test_dask_wrappers_pass_min_disparity() -> None:
    da = pytest.importorskip("dask.array", reason="dask (the batch extra) is not installed")
    import stereodepth.dask as sdd

    rng = np.random.default_rng(5)
    d = np.stack([float_map(rng, 16, (9, 14)) for _ in range(3)])
    raw = stereodepth.to_opencv_disparity(d, min_disparity=16)
    lazy = da.from_array(raw, chunks=(1, 9, 14))
    kw = {"focal_px": FOCAL_PX, "baseline_m": BASELINE_M, "min_disparity": 16}
    assert_same(
        sdd.disparity_to_depth(lazy, **kw).compute(), stereodepth.disparity_to_depth(raw, **kw)
    )
    assert_same(sdd.reproject(lazy, **kw).compute(), stereodepth.reproject(raw, **kw))
    assert np.isnan(sdd.disparity_to_depth(lazy, **kw).compute()[np.isnan(d)]).all()


# --- real OpenCV output ----------------------------------------------------------------------


def _grey(scene: Any) -> tuple[np.ndarray, np.ndarray]:
    cv2 = pytest.importorskip("cv2", reason="OpenCV (opencv-python-headless) is not installed")
    left, right = read_image(scene.left_path), read_image(scene.right_path)
    if left.ndim == 3:
        left = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
        right = cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)
    return left, right


def _opencv_matchers(min_disparity: int, num_disparities: int) -> list[tuple[str, Any]]:
    cv2 = pytest.importorskip("cv2", reason="OpenCV (opencv-python-headless) is not installed")
    bm = cv2.StereoBM_create(numDisparities=num_disparities, blockSize=9)
    bm.setMinDisparity(min_disparity)
    sgbm = cv2.StereoSGBM_create(
        minDisparity=min_disparity, numDisparities=num_disparities, blockSize=5, P1=200, P2=800
    )
    return [("bm", bm), ("sgbm", sgbm)]


def _scene(scenes: list[Any], name: str) -> Any:
    found = [s for s in scenes if s.name == name]
    if not found:
        pytest.skip(f"scene {name} not in the shared data")
    return found[0]


@pytest.mark.data
def test_real_opencv_output_with_min_disparity_16(stereo_scenes: list[Any]) -> None:
    """Teddy (disparities up to 53) searched over 16..63: holes are +240."""
    left, right = _grey(_scene(stereo_scenes, "mb2003-teddy"))
    for name, matcher in _opencv_matchers(16, 48):
        raw = matcher.compute(left, right)
        holes = raw < 16 * 16
        assert (raw == 240).any(), name
        assert (raw[holes] == 240).all(), name
        z = stereodepth.disparity_to_depth(
            raw, focal_px=FOCAL_PX, baseline_m=BASELINE_M, min_disparity=16
        )
        assert (np.isnan(z) == holes).all(), name
        d = stereodepth.from_opencv_disparity(raw, min_disparity=16)
        assert_same(z, stereodepth.disparity_to_depth(d, focal_px=FOCAL_PX, baseline_m=BASELINE_M))
        xyz = stereodepth.reproject(raw, focal_px=FOCAL_PX, baseline_m=BASELINE_M, min_disparity=16)
        assert (np.isnan(xyz[..., 2]) == holes).all(), name
        assert_same(xyz, stereodepth.reproject(d, focal_px=FOCAL_PX, baseline_m=BASELINE_M))


@pytest.mark.data
def test_real_opencv_negative_disparities_with_doffs(stereo_scenes: list[Any]) -> None:
    """Tsukuba (disparities 0..14) with the left image cropped by 16 columns: every true
    disparity is d - 16 < 0, searched over -16..15. With doffs_px = 20 (a converging rig) each
    is a finite depth f*B/(d + 20); only OpenCV's holes (-272) are dropped."""
    left, right = _grey(_scene(stereo_scenes, "mb2001-tsukuba"))
    s = 16
    left, right = np.ascontiguousarray(left[:, s:]), np.ascontiguousarray(right[:, :-s])
    kw = {"focal_px": FOCAL_PX, "baseline_m": BASELINE_M, "doffs_px": 20.0}
    for name, matcher in _opencv_matchers(-16, 32):
        raw = matcher.compute(left, right)
        holes = raw < -16 * 16
        assert (raw[holes] == -272).all(), name
        negative = (raw < 0) & ~holes
        assert negative.mean() > 0.5, name  # most of the scene
        z = stereodepth.disparity_to_depth(raw, min_disparity=-16, **kw)
        assert (np.isnan(z) == holes).all(), name
        d = stereodepth.from_opencv_disparity(raw, min_disparity=-16)
        assert_same(z, stereodepth.disparity_to_depth(d, **kw))
        np.testing.assert_allclose(
            z[negative], FOCAL_PX * BASELINE_M / (raw[negative] / 16 + 20.0), rtol=1e-6
        )
        xyz = stereodepth.reproject(raw, min_disparity=-16, **kw)
        assert (np.isnan(xyz[..., 2]) == holes).all(), name
        assert_same(xyz, stereodepth.reproject(d, **kw))
