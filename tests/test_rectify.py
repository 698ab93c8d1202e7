"""Rectification: stereo_rectify and the maps against OpenCV, remap against its numpy oracle
(and OpenCV), StereoRectifier, and every rejected input."""

from __future__ import annotations

import dataclasses
import sys
import threading
import warnings
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import stereodepth
from stereodepth import _core, reference
from stereodepth.rectify import StereoRectifier, stereo_rectify

ALPHAS = [-1.0, 0.0, 0.5, 1.0]


def rotation(rvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula (test-side, so that the tests need no OpenCV to build rigs)."""
    theta = float(np.linalg.norm(rvec))
    if theta == 0:
        return np.eye(3)
    k = rvec / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * (kx @ kx)


@dataclass(frozen=True)
class Rig:
    name: str
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    size: tuple[int, int]
    R: np.ndarray
    T: np.ndarray
    model: str = "plumb_bob"


def make_rig(name: str, seed: int, *, vertical: bool = False, ncoef: int = 5) -> Rig:
    rng = np.random.default_rng(seed)
    w, h = (640, 480) if seed % 2 == 0 else (1241, 376)

    def k() -> np.ndarray:
        f = 0.9 * w + rng.normal() * 20
        return np.array(
            [[f, 0, w / 2 + rng.normal() * 8], [0, f * (1 + rng.normal() * 0.01), h / 2], [0, 0, 1]]
        )

    coefs = {
        0: [],
        4: [-0.28, 0.07, 0.0012, -0.0008],
        5: [-0.25, 0.08, 0.001, -0.0005, -0.01],
        8: [-0.3, 0.1, 0.001, -0.0007, 0.01, 0.05, 0.02, 0.003],
    }[ncoef]
    d1 = np.array(coefs) * (1 + 0.1 * rng.normal())
    d2 = np.array(coefs) * (1 + 0.1 * rng.normal())
    r = rotation(rng.normal(size=3) * 0.02)
    t = np.array([0.003, -0.11, 0.002]) if vertical else np.array([-0.12, 0.003, 0.002])
    model = "none" if ncoef == 0 else "plumb_bob"
    return Rig(name, k(), d1, k(), d2, (w, h), r, t + rng.normal(size=3) * 1e-3, model)


RIGS = [
    make_rig("h5", 0),
    make_rig("h4-kitti-size", 1, ncoef=4),
    make_rig("h8", 2, ncoef=8),
    make_rig("v5", 3, vertical=True),
    make_rig("v8", 4, vertical=True, ncoef=8),
    make_rig("pinhole", 5, ncoef=0),
]


@pytest.fixture(scope="module")
def cv2() -> Any:
    return pytest.importorskip("cv2", reason="OpenCV (opencv-python-headless) is not installed")


def cv_dist(d: np.ndarray) -> np.ndarray | None:
    return d if d.size else None


def assert_rel(a: np.ndarray, b: np.ndarray, rtol: float = 1e-9) -> None:
    """Equal within rtol relative to the largest entry of the reference matrix."""
    scale = max(float(np.abs(b).max()), 1e-300)
    assert float(np.abs(a - b).max()) <= rtol * scale, (a, b)


# --- stereo_rectify ------------------------------------------------------------------------------
@pytest.mark.parametrize("count", [12, 14])
def test_opencv_thin_prism_and_tilted_forms_with_zero_terms(cv2: Any, count: int) -> None:
    # cv2.stereoCalibrate with CALIB_RATIONAL_MODEL returns D1, D2 of shape (1, 14), zeros
    # after the 8th (OpenCV 5.0, checked); OpenCV takes them everywhere, and so do the
    # calibration readers, but stereo_rectify, init_undistort_rectify_map and
    # StereoRectifier refused them ("must have 4 or 5 or 8 coefficients").
    rig = RIGS[2]  # the rational model's 8
    d1, d2 = np.zeros(count), np.zeros(count)
    d1[:8], d2[:8] = rig.D1, rig.D2
    got = stereo_rectify(rig.K1, d1, rig.K2, d2, rig.size, rig.R, rig.T, alpha=0.0)
    want = cv2.stereoRectify(rig.K1, d1, rig.K2, d2, rig.size, rig.R, rig.T.reshape(3, 1),
                             flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0)  # fmt: skip
    for a, b in zip(got[:5], want[:5], strict=True):
        assert_rel(a, b)
    same = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T, alpha=0.0)
    for a, b in zip(got[:5], same[:5], strict=True):
        np.testing.assert_array_equal(a, b)
    mx, my = stereodepth.init_undistort_rectify_map(rig.K1, d1, got.R1, got.P1, rig.size)
    cx, cy = cv2.initUndistortRectifyMap(rig.K1, d1, got.R1, got.P1, rig.size, cv2.CV_32FC1)
    np.testing.assert_array_equal(mx, cx)
    np.testing.assert_array_equal(my, cy)
    rect = StereoRectifier(K1=rig.K1, D1=d1, K2=rig.K2, D2=d2, R=rig.R, T=rig.T,
                           image_size=rig.size, alpha=0.0)  # fmt: skip
    np.testing.assert_array_equal(rect.maps("left")[0], mx)
    d1[count - 1] = 1e-3  # a tilt or thin prism term: a model the rectifier does not have
    with pytest.raises(
        ValueError, match=f"D1 has thin prism or tilt terms .coefficients 9 to {count}"
    ):
        stereo_rectify(rig.K1, d1, rig.K2, d2, rig.size, rig.R, rig.T)
    d1[count - 1] = np.nan
    with pytest.raises(ValueError, match="D1 must be finite"):
        stereo_rectify(rig.K1, d1, rig.K2, d2, rig.size, rig.R, rig.T)


@pytest.mark.parametrize("zero_disparity", [True, False], ids=["zero-disp", "free-cx"])
@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
def test_stereo_rectify_matches_opencv(
    cv2: Any, rig: Rig, alpha: float, zero_disparity: bool
) -> None:
    flags = cv2.CALIB_ZERO_DISPARITY if zero_disparity else 0
    want = cv2.stereoRectify(
        rig.K1,
        cv_dist(rig.D1),
        rig.K2,
        cv_dist(rig.D2),
        rig.size,
        rig.R,
        rig.T.reshape(3, 1),
        flags=flags,
        alpha=alpha,
    )
    got = stereo_rectify(
        rig.K1,
        rig.D1,
        rig.K2,
        rig.D2,
        rig.size,
        rig.R,
        rig.T,
        alpha=alpha,
        zero_disparity=zero_disparity,
        distortion_model=rig.model,
    )
    for name, a, b in zip(("R1", "R2", "P1", "P2", "Q"), got[:5], want[:5], strict=True):
        assert a.dtype == np.float64 and a.shape == b.shape, name
        assert_rel(a, b)
    # The ROIs round edges that can fall exactly on a pixel boundary (ceil of +-1e-13).
    for a, b in ((got.roi1, want[5]), (got.roi2, want[6])):
        assert np.abs(np.array(a) - np.array(b)).max() <= 1, (a, b)


@pytest.mark.parametrize("new_size", [(800, 600), (320, 240), (1000, 480)])
@pytest.mark.parametrize("alpha", [-1.0, 0.0, 1.0])
def test_new_image_size_matches_opencv(cv2: Any, new_size: tuple[int, int], alpha: float) -> None:
    rig = RIGS[0]
    want = cv2.stereoRectify(
        rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T.reshape(3, 1), alpha=alpha,
        newImageSize=new_size, flags=cv2.CALIB_ZERO_DISPARITY,
    )  # fmt: skip
    got = stereo_rectify(
        rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T, alpha=alpha,
        new_image_size=new_size,
    )  # fmt: skip
    for a, b in zip(got[:5], want[:5], strict=True):
        assert_rel(a, b)


def fisheye_rig(seed: int) -> Rig:
    r = np.random.default_rng(seed)

    def k() -> np.ndarray:
        return np.array(
            [[420 + r.normal() * 5, 0, 640 + r.normal() * 3],
             [0, 421 + r.normal() * 5, 400 + r.normal() * 3], [0, 0, 1]]
        )  # fmt: skip

    d = np.array([0.05, -0.01, 0.003, -0.0006])
    return Rig(
        f"fisheye{seed}", k(), d * (1 + 0.1 * r.normal()), k(), d * (1 + 0.1 * r.normal()),
        (1280, 800), rotation(r.normal(size=3) * 0.02),
        np.array([-0.1, 0.002, 0.001]) + r.normal(size=3) * 1e-3, "equidistant",
    )  # fmt: skip


@pytest.mark.parametrize("new_size", [None, (800, 500)])
@pytest.mark.parametrize("zero_disparity", [True, False], ids=["zero-disp", "free-cx"])
@pytest.mark.parametrize(("balance", "fov_scale"), [(0.0, 1.0), (0.5, 1.0), (1.0, 1.3)])
@pytest.mark.parametrize("seed", [0, 1])
def test_fisheye_stereo_rectify_matches_opencv(
    cv2: Any,
    seed: int,
    balance: float,
    fov_scale: float,
    zero_disparity: bool,
    new_size: tuple[int, int] | None,
) -> None:
    rig = fisheye_rig(seed)
    want = cv2.fisheye.stereoRectify(
        rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T.reshape(3, 1),
        cv2.CALIB_ZERO_DISPARITY if zero_disparity else 0, newImageSize=new_size or (0, 0),
        balance=balance, fov_scale=fov_scale,
    )  # fmt: skip
    got = stereo_rectify(
        rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T, new_image_size=new_size,
        zero_disparity=zero_disparity, distortion_model="equidistant", balance=balance,
        fov_scale=fov_scale,
    )  # fmt: skip
    for a, b in zip(got[:5], want, strict=True):
        assert_rel(a, b)
    assert got.roi1 == got.roi2 == (0, 0, *(new_size or rig.size))


def test_fisheye_rectifier_maps_match_opencv(cv2: Any) -> None:
    rig = fisheye_rig(2)
    rect = StereoRectifier.from_calibration(calib_of(rig), balance=0.3)
    want = cv2.fisheye.stereoRectify(
        rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T.reshape(3, 1),
        cv2.CALIB_ZERO_DISPARITY, balance=0.3,
    )  # fmt: skip
    want_x, want_y = cv2.fisheye.initUndistortRectifyMap(
        rig.K2, rig.D2, want[1], want[3], rig.size, cv2.CV_32FC1
    )
    got_x, got_y = rect.maps("right")
    assert np.abs(got_x - want_x).max() <= 1e-3
    assert np.abs(got_y - want_y).max() <= 1e-3


@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
def test_stereo_rectify_matches_oracle(rig: Rig, alpha: float) -> None:
    """Native against the numpy oracle (no OpenCV needed), both principal-point rules."""
    for zero_disparity in (True, False):
        for new_size in (None, (800, 500)):
            kw = {"alpha": alpha, "zero_disparity": zero_disparity,
                  "new_image_size": new_size, "distortion_model": rig.model}  # fmt: skip
            args = (rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T)
            got = stereo_rectify(*args, **kw)
            want = reference.stereo_rectify(*args, **kw)
            for a, b in zip(got[:5], want[:5], strict=True):
                assert_rel(a, b, 1e-12)
            for a, b in ((got.roi1, want.roi1), (got.roi2, want.roi2)):
                assert np.abs(np.array(a) - np.array(b)).max() <= 1, (a, b)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fisheye_stereo_rectify_matches_oracle(seed: int) -> None:
    rig = fisheye_rig(seed)
    args = (rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T)
    for balance, fov_scale, zd, new_size in [(0.0, 1.0, True, None), (0.6, 1.2, False, (900, 600))]:
        kw = {"distortion_model": "equidistant", "balance": balance, "fov_scale": fov_scale,
              "zero_disparity": zd, "new_image_size": new_size}  # fmt: skip
        got, want = stereo_rectify(*args, **kw), reference.stereo_rectify(*args, **kw)
        for a, b in zip(got, want, strict=True):
            if isinstance(a, tuple):
                assert a == b
            else:
                assert_rel(a, b, 1e-12)


def test_undistort_points_matches_oracle() -> None:
    rng = np.random.default_rng(6)
    pts = rng.random((300, 2)) * [640, 480] - [20, 20]
    for rig in RIGS:
        got = _core.undistort_points(rig.K1, rig.D1, rig.model, pts)
        np.testing.assert_allclose(got, reference.undistort_points(pts, rig.K1, rig.D1, rig.model),
                                   rtol=0, atol=1e-14)  # fmt: skip
    K, D = fisheye_camera()
    got = _core.undistort_points(K, D, "equidistant", pts)
    want = reference.undistort_points(pts, K, D, "equidistant")
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)


_K = [[50.0, 0.0, 30.0], [0.0, 50.0, 25.0], [0.0, 0.0, 1.0]]
_D = [-0.1, 0.01, 0.0, 0.0, 0.0]


@pytest.mark.parametrize(
    ("T", "kw", "error", "message"),
    [
        ([0, 0, 0], {}, ValueError, "T must not be zero"),
        ([1e-200, 0, 0], {}, ValueError, "T must not be zero"),  # its length underflows
        ([0, 0, 1.0], {}, ValueError, "T must lie mostly across the optical axis"),
        ([-0.1, 0, 0], {"distortion_model": "equidistant", "alpha": 0.0}, ValueError,
         "alpha applies to pinhole models"),
        ([-0.1, 0, 0], {"distortion_model": "equidistant", "balance": 2}, ValueError,
         r"balance must be in \[0, 1\]"),
        ([-0.1, 0, 0], {"distortion_model": "equidistant", "fov_scale": 0}, ValueError,
         "fov_scale"),
        ([-0.1, 0, 0], {"distortion_model": "equidistant", "fov_scale": -1.0}, ValueError,
         "fov_scale"),
        ([-0.1, 0, 0], {"balance": 0.5}, ValueError, "balance and fov_scale apply to equidistant"),
        ([-0.1, 0, 0], {"fov_scale": 2.0}, ValueError, "balance and fov_scale apply to"),
        ([-0.1, 0, 0], {"alpha": "0"}, TypeError, "alpha"),
    ],
)  # fmt: skip
def test_oracle_refuses_what_the_native_rectification_refuses(
    T: Any, kw: dict[str, Any], error: type[Exception], message: str
) -> None:
    # The oracle checked the arguments in part: a zero T gave ZeroDivisionError, cameras one
    # behind the other, alpha with an equidistant rig and balance or fov_scale with a pinhole
    # one were taken, and fov_scale <= 0 was read as 1. Both now share one set of checks.
    d = _D[:4] if kw.get("distortion_model") == "equidistant" else _D
    for rectify in (stereo_rectify, reference.stereo_rectify):
        with pytest.raises(error, match=message):
            rectify(_K, d, _K, d, (60, 50), np.eye(3), T, **kw)


@pytest.mark.parametrize(
    ("points", "K", "D", "model", "error", "message"),
    [
        ([[10.0, 20.0]], _K, _D, "fisheye", ValueError, "model must be one of"),
        ([[10.0, 20.0]], _K, _D, "none", ValueError, "D must be empty or zero"),
        ([[10.0, 20.0]], _K, [0.1] * 14, "plumb_bob", ValueError, "D has thin prism"),
        ([[10.0, 20.0]], _K, [0.1] * 6, "plumb_bob", ValueError, "D must have 4 or 5 or 8"),
        ([[10.0, 20.0]], [[50, 1, 30], [0, 50, 25], [0, 0, 1]], _D, "plumb_bob", ValueError,
         "K must have the form"),
        ([[10.0, 20.0]], [[1, 2], [3, 4]], _D, "plumb_bob", ValueError, r"K must have shape"),
        ([[10.0, 20.0, 1.0], [90.0, 70.0, 1.0]], _K, _D, "plumb_bob", ValueError,
         r"points must have shape \(N, 2\), got shape \(2, 3\)"),
        ("points", _K, _D, "plumb_bob", TypeError, "points must be a real number or array"),
    ],
)  # fmt: skip
def test_undistort_points_oracle_checks_its_arguments(
    points: Any, K: Any, D: Any, model: str, error: type[Exception], message: str
) -> None:
    # It checked nothing: a misspelt model was read as no distortion, a D with model "none"
    # ignored, D None gave NaN and points of shape (2, 3) were read as three points.
    with pytest.raises(error, match=message):
        reference.undistort_points(points, K, D, model)


def test_undistort_points_oracle_takes_d_none_as_no_distortion() -> None:
    pts = np.array([[10.0, 20.0], [90.0, 70.0]])
    got = reference.undistort_points(pts, _K, None)
    np.testing.assert_array_equal(got, (pts - [30.0, 25.0]) / 50.0)


def test_rectified_cameras_are_row_aligned() -> None:
    """Property of any rectification: a 3-D point projects to the same row in both images."""
    rig = RIGS[0]
    r = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T, alpha=0.0)
    rng = np.random.default_rng(3)
    x1 = np.c_[rng.uniform(-1, 1, (20, 2)), rng.uniform(2, 10, 20)]  # left camera frame
    x2 = (rig.R @ x1.T).T + rig.T
    p1 = (r.P1[:, :3] @ (r.R1 @ x1.T)).T
    p2 = (r.P1[:, :3] @ (r.R2 @ x2.T)).T
    np.testing.assert_allclose(p1[:, 1] / p1[:, 2], p2[:, 1] / p2[:, 2], atol=1e-9)
    # and the projections P1, P2 of the rectified left-frame point agree with those rows
    xr = np.c_[(r.R1 @ x1.T).T, np.ones(20)]
    q2 = (r.P2 @ xr.T).T
    np.testing.assert_allclose(q2[:, 0] / q2[:, 2], p2[:, 0] / p2[:, 2], atol=1e-9)


def test_undistort_points_matches_opencv(cv2: Any) -> None:
    rng = np.random.default_rng(5)
    pts = rng.random((200, 2)) * [640, 480]
    for rig in RIGS[:3]:
        want = cv2.undistortPoints(pts.reshape(-1, 1, 2), rig.K1, rig.D1).reshape(-1, 2)
        got = _core.undistort_points(rig.K1, rig.D1, "plumb_bob", pts)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    kf, df = fisheye_camera()
    want = cv2.fisheye.undistortPoints(pts.reshape(-1, 1, 2), kf, df).reshape(-1, 2)
    got = _core.undistort_points(kf, df, "equidistant", pts)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


# --- maps ----------------------------------------------------------------------------------------
def fisheye_camera() -> tuple[np.ndarray, np.ndarray]:
    return (
        np.array([[400.0, 0, 321.5], [0, 401.0, 238.25], [0, 0, 1]]),
        np.array([0.05, -0.012, 0.002, -0.0004]),
    )


@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
def test_maps_match_opencv(cv2: Any, rig: Rig) -> None:
    r = stereo_rectify(
        rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T, alpha=0.5,
        distortion_model=rig.model,
    )  # fmt: skip
    for K, D, Rk, Pk in ((rig.K1, rig.D1, r.R1, r.P1), (rig.K2, rig.D2, r.R2, r.P2)):
        want_x, want_y = cv2.initUndistortRectifyMap(K, cv_dist(D), Rk, Pk, rig.size, cv2.CV_32FC1)
        got_x, got_y = stereodepth.init_undistort_rectify_map(K, D, Rk, Pk, rig.size, rig.model)
        assert got_x.dtype == np.float32 and got_x.shape == (rig.size[1], rig.size[0])
        assert np.abs(got_x - want_x).max() <= 1e-3
        assert np.abs(got_y - want_y).max() <= 1e-3


def test_fisheye_maps_match_opencv(cv2: Any) -> None:
    K, D = fisheye_camera()
    R = rotation(np.array([0.01, 0.02, -0.01]))
    P = np.array([[300.0, 0, 330], [0, 300, 250], [0, 0, 1]])
    want_x, want_y = cv2.fisheye.initUndistortRectifyMap(K, D, R, P, (640, 480), cv2.CV_32FC1)
    got_x, got_y = stereodepth.init_undistort_rectify_map(K, D, R, P, (640, 480), "equidistant")
    assert np.abs(got_x - want_x).max() <= 1e-3
    assert np.abs(got_y - want_y).max() <= 1e-3


@pytest.mark.parametrize("rig", RIGS[:3], ids=lambda r: r.name)
def test_maps_match_oracle_exactly(rig: Rig) -> None:
    r = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T)
    got = stereodepth.init_undistort_rectify_map(rig.K1, rig.D1, r.R1, r.P1, rig.size, threads=2)
    want = reference.init_undistort_rectify_map(rig.K1, rig.D1, r.R1, r.P1, rig.size)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b, strict=True)


def test_fisheye_maps_match_oracle() -> None:
    """Float32-exact but for atan, whose last bit may differ between math libraries."""
    K, D = fisheye_camera()
    R = rotation(np.array([0.01, 0.02, -0.01]))
    P = np.array([[300.0, 0, 330], [0, 300, 250], [0, 0, 1]])
    got = stereodepth.init_undistort_rectify_map(K, D, R, P, (333, 251), "equidistant")
    want = reference.init_undistort_rectify_map(K, D, R, P, (333, 251), "equidistant")
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_max_ulp(a, b, maxulp=1)


def test_maps_do_not_depend_on_threads() -> None:
    rig = RIGS[2]
    r = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T)
    one = stereodepth.init_undistort_rectify_map(rig.K1, rig.D1, r.R1, r.P1, rig.size, threads=1)
    for n in (2, 3, 7):
        many = stereodepth.init_undistort_rectify_map(
            rig.K1, rig.D1, r.R1, r.P1, rig.size, threads=n
        )
        for a, b in zip(one, many, strict=True):
            np.testing.assert_array_equal(a, b)


# --- remap ---------------------------------------------------------------------------------------
def random_maps(
    rng: np.random.Generator, out_shape: tuple[int, int], src_shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Positions over the image and a little beyond, with the special cases scattered in:
    whole and half pixels, the last row/column, just outside, NaN, huge values."""
    h, w = src_shape
    mx = (rng.random(out_shape) * (w + 3) - 1.5).astype(np.float32)
    my = (rng.random(out_shape) * (h + 3) - 1.5).astype(np.float32)
    special = np.array(
        [0, -1, -0.5, -1 / 2048, w - 1, w - 0.5, w, w - 1 + 1 / 2048, 0.5 / 1024, 3 / 2048,
         np.nan, np.inf, -np.inf, 1e9, -1e9, 7.999999],
        dtype=np.float32,
    )  # fmt: skip
    for m in (mx, my):
        flat = m.reshape(-1)
        idx = rng.choice(flat.size, size=min(flat.size, 3 * special.size), replace=False)
        flat[idx] = np.resize(special, idx.size)
    return mx, my


def random_image(rng: np.random.Generator, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    top = np.iinfo(dtype).max
    img = rng.integers(0, top + 1, size=shape, dtype=np.int64)
    img.reshape(-1)[:: max(1, img.size // 7)] = top  # edge values
    img.reshape(-1)[1 :: max(1, img.size // 5)] = 0
    return img.astype(dtype)


FORMATS = [((), np.uint8), ((), np.uint16), ((3,), np.uint8)]
FORMAT_IDS = ["grey8", "grey16", "rgb8"]


@pytest.mark.parametrize("fmt", FORMATS, ids=FORMAT_IDS)
@pytest.mark.parametrize(
    ("src_shape", "out_shape"),
    [((1, 1), (3, 5)), ((1, 9), (2, 9)), ((9, 1), (9, 2)), ((7, 13), (7, 13)),
     ((37, 1023), (19, 1023)), ((64, 80), (33, 17)), ((2, 2), (1, 1))],
)  # fmt: skip
def test_remap_matches_oracle(
    fmt: tuple[tuple[int, ...], type], src_shape: tuple[int, int], out_shape: tuple[int, int]
) -> None:
    extra, dtype = fmt
    rng = np.random.default_rng(zlib.crc32(repr((src_shape, out_shape, extra, dtype)).encode()))
    img = random_image(rng, src_shape + extra, dtype)
    mx, my = random_maps(rng, out_shape, src_shape)
    want = reference.remap(img, mx, my)
    got = stereodepth.remap(img, mx, my)
    assert got.dtype == img.dtype and got.shape == out_shape + extra
    np.testing.assert_array_equal(got, want, strict=True)


@pytest.mark.parametrize("fmt", FORMATS, ids=FORMAT_IDS)
def test_remap_every_isa_and_thread_count_agree(fmt: tuple[tuple[int, ...], type]) -> None:
    extra, dtype = fmt
    rng = np.random.default_rng(17)
    img = random_image(rng, (120, 161, *extra), dtype)
    mx, my = random_maps(rng, (97, 203), (120, 161))
    precision = "float" if dtype == np.uint16 else "fixed"
    table = _core.RemapTable(mx, my, 120, 161, precision, 1)
    want = np.empty((97, 203, *extra), dtype)
    table.apply(img, want, 1, "baseline")
    np.testing.assert_array_equal(want, reference.remap(img, mx, my))
    for isa in stereodepth.build_info()["supported_isas"]:
        for threads in (1, 2, 5):
            got = np.empty_like(want)
            table.apply(img, got, threads, isa)
            np.testing.assert_array_equal(got, want, err_msg=f"{isa} threads={threads}")


@pytest.mark.parametrize("fmt", FORMATS, ids=FORMAT_IDS)
def test_remap_within_one_level_of_opencv(cv2: Any, fmt: tuple[tuple[int, ...], type]) -> None:
    """cv2.remap with float32 maps, INTER_LINEAR, BORDER_CONSTANT 0 (OpenCV 5 interpolates
    in float32): within 1 grey level everywhere, including outside and on the border."""
    extra, dtype = fmt
    rng = np.random.default_rng(23)
    img = random_image(rng, (91, 131, *extra), dtype)
    mx, my = random_maps(rng, (77, 141), (91, 131))
    finite = np.isfinite(mx) & np.isfinite(my) & (np.abs(mx) < 1e6) & (np.abs(my) < 1e6)
    mx, my = np.where(finite, mx, -5), np.where(finite, my, -5)  # OpenCV's NaN is undefined
    want = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    got = stereodepth.remap(img, mx, my)
    assert np.abs(got.astype(np.int64) - want).max() <= 1


def test_remap_rectification_within_one_level_of_opencv(cv2: Any) -> None:
    rig = RIGS[0]
    r = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T, alpha=1.0)
    mx, my = stereodepth.init_undistort_rectify_map(rig.K1, rig.D1, r.R1, r.P1, rig.size)
    rng = np.random.default_rng(2)
    img = random_image(rng, (rig.size[1], rig.size[0], 3), np.uint8)
    want = cv2.remap(img, mx, my, cv2.INTER_LINEAR)
    got = stereodepth.remap(img, mx, my, threads=2)
    assert np.abs(got.astype(np.int64) - want).max() <= 1
    np.testing.assert_array_equal(got, reference.remap(img, mx, my))


@settings(max_examples=25, deadline=None)
@given(
    h=st.integers(1, 40),
    w=st.integers(1, 70),
    dtype=st.sampled_from([np.uint8, np.uint16]),
    seed=st.integers(0, 2**32 - 1),
)
def test_remap_integer_positions_copy_pixels(h: int, w: int, dtype: type, seed: int) -> None:
    """Whole-pixel positions give the pixels themselves; outside ones give 0."""
    rng = np.random.default_rng(seed)
    img = random_image(rng, (h, w), dtype)
    ys = rng.integers(-2, h + 2, size=(5, 9))
    xs = rng.integers(-2, w + 2, size=(5, 9))
    got = stereodepth.remap(img, xs.astype(np.float32), ys.astype(np.float32))
    inside = (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)
    want = np.where(inside, img[np.clip(ys, 0, h - 1), np.clip(xs, 0, w - 1)], 0)
    np.testing.assert_array_equal(got, want.astype(dtype))


def test_remap_from_several_python_threads() -> None:
    rng = np.random.default_rng(8)
    img = random_image(rng, (200, 300), np.uint8)
    mx, my = random_maps(rng, (180, 310), (200, 300))
    want = reference.remap(img, mx, my)
    errors: list[BaseException] = []

    def work() -> None:
        try:
            for _ in range(5):
                np.testing.assert_array_equal(stereodepth.remap(img, mx, my, threads=2), want)
        except BaseException as exc:  # reported below
            errors.append(exc)

    workers = [threading.Thread(target=work) for _ in range(4)]
    for t in workers:
        t.start()
    for t in workers:
        t.join()
    assert not errors


def test_one_rectifier_from_several_python_threads() -> None:
    rig = RIGS[1]
    rect = StereoRectifier.from_calibration(calib_of(rig), alpha=0.0, threads=2)
    rng = np.random.default_rng(12)
    shape = (rig.size[1], rig.size[0])
    pairs = [(random_image(rng, shape, np.uint8), random_image(rng, shape, np.uint8))
             for _ in range(3)]  # fmt: skip
    want = [rect.rectify(a, b) for a, b in pairs]
    errors: list[BaseException] = []

    def work(i: int) -> None:
        try:
            for _ in range(3):
                got = rect.rectify(*pairs[i % 3])
                for g, w in zip(got, want[i % 3], strict=True):
                    np.testing.assert_array_equal(g, w)
        except BaseException as exc:  # reported below
            errors.append(exc)

    workers = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in workers:
        t.start()
    for t in workers:
        t.join()
    assert not errors


def test_remap_writes_into_out_and_accepts_float64_maps() -> None:
    rng = np.random.default_rng(4)
    img = random_image(rng, (20, 30), np.uint16)
    mx, my = random_maps(rng, (10, 12), (20, 30))
    out = np.empty((10, 12), np.uint16)
    got = stereodepth.remap(img, mx.astype(np.float64), my.astype(np.float64), out=out)
    assert got is out
    np.testing.assert_array_equal(out, reference.remap(img, mx, my))


@pytest.mark.parametrize("remap", [stereodepth.remap, reference.remap], ids=["native", "oracle"])
def test_remap_float64_maps_beyond_float32(remap: Any) -> None:
    # A float64 map may mark "no source" with a huge value (1e300, finfo.max): rounded to
    # float32 it is +-inf, which the clamp puts outside the image (0), as the docstring says.
    # The rounding printed numpy's "RuntimeWarning: overflow encountered in cast" (an error
    # under -W error) before the image came out right.
    rng = np.random.default_rng(12)
    img = random_image(rng, (6, 7), np.uint8)
    mx, my = random_maps(rng, (4, 5), (6, 7))
    big_x, big_y = mx.astype(np.float64), my.astype(np.float64)
    big_x[0, :3] = [1e300, -1e300, np.finfo(np.float64).max]
    big_y[1, :2] = [1e300, -np.inf]
    f32_max = float(np.finfo(np.float32).max)
    small_x, small_y = (
        np.where(np.abs(m) > f32_max, np.copysign(np.inf, m), m).astype(np.float32)
        for m in (big_x, big_y)
    )
    expected = stereodepth.remap(img, small_x, small_y)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = remap(img, big_x, big_y)
    np.testing.assert_array_equal(got, expected)
    assert (got[0, :3] == 0).all() and (got[1, :2] == 0).all()


# --- StereoRectifier -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Calib:
    """A stand-in with the fields of stereodepth.calib.StereoCalibration."""

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    distortion_model: str
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]
    R1: np.ndarray | None = None
    R2: np.ndarray | None = None
    P1: np.ndarray | None = None
    P2: np.ndarray | None = None
    Q: np.ndarray | None = None
    rectified: bool = False
    source: str = "test"


def calib_of(rig: Rig, **kw: Any) -> Calib:
    return Calib(rig.K1, rig.D1, rig.K2, rig.D2, rig.model, rig.R, rig.T, rig.size, **kw)


def test_rectifier_matches_the_three_steps() -> None:
    rig = RIGS[0]
    rect = StereoRectifier.from_calibration(calib_of(rig), alpha=0.0, threads=2)
    r = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T, alpha=0.0)
    for a, b in zip((rect.R1, rect.R2, rect.P1, rect.P2, rect.Q), r[:5], strict=True):
        np.testing.assert_array_equal(a, b)
    rng = np.random.default_rng(1)
    left = random_image(rng, (rig.size[1], rig.size[0]), np.uint8)
    right = random_image(rng, (rig.size[1], rig.size[0]), np.uint8)
    got_l, got_r = rect.rectify(left, right)
    for got, img, (K, D, Rk, Pk) in (
        (got_l, left, (rig.K1, rig.D1, r.R1, r.P1)),
        (got_r, right, (rig.K2, rig.D2, r.R2, r.P2)),
    ):
        mx, my = stereodepth.init_undistort_rectify_map(K, D, Rk, Pk, rig.size)
        np.testing.assert_array_equal(got, reference.remap(img, mx, my))
    np.testing.assert_array_equal(rect.maps("left")[0], stereodepth.init_undistort_rectify_map(
        rig.K1, rig.D1, r.R1, r.P1, rig.size)[0])  # fmt: skip


def test_rectifier_rig_and_q() -> None:
    rig = RIGS[0]
    rect = StereoRectifier(
        K1=rig.K1, D1=rig.D1, K2=rig.K2, D2=rig.D2, R=rig.R, T=rig.T, image_size=rig.size
    )
    sr = rect.rig
    assert sr.focal_px == rect.P1[0, 0]
    assert sr.baseline_mm == pytest.approx(np.linalg.norm(rig.T) * 1000, rel=1e-12)
    assert sr.doffs_px == 0.0  # zero_disparity
    assert (sr.width_px, sr.height_px) == rig.size
    # Q and the rig agree on depth: a disparity d at the principal point is at f B / d.
    d = 40.0
    xyzw = rect.Q @ np.array([rect.P1[0, 2], rect.P1[1, 2], d, 1.0])
    assert xyzw[2] / xyzw[3] == pytest.approx(sr.depth_m(d), rel=1e-12)
    vertical = RIGS[3]
    rv = StereoRectifier.from_calibration(calib_of(vertical))
    assert rv.vertical and not rect.vertical
    assert rv.rig.baseline_mm == pytest.approx(np.linalg.norm(vertical.T) * 1000, rel=1e-12)
    # Swapped cameras (the first is the right one, T[0] > 0): Q says negative disparities,
    # which no matcher here searches, so the rig refuses rather than report a baseline whose
    # sign disagrees with Q.
    swapped = calib_of(dataclasses.replace(rig, R=rig.R.T, T=-rig.R.T @ rig.T))
    rs = StereoRectifier.from_calibration(swapped)
    assert rs.P2[0, 3] > 0
    with pytest.raises(ValueError, match=r"first camera is right of the second: T = \[.*swap"):
        rs.rig  # noqa: B018 - the property raises
    upside = calib_of(dataclasses.replace(vertical, R=vertical.R.T, T=-vertical.R.T @ vertical.T))
    below = r"first camera is below the second: T = .* T\[1\] < 0 when the upper camera is first"
    with pytest.raises(ValueError, match=below):
        StereoRectifier.from_calibration(upside).rig  # noqa: B018 - the property raises


def _refusal(calib: Calib) -> str:
    """The message of the rig of a calibration that names the cameras wrongly."""
    with pytest.raises(
        ValueError, match=r"^the first camera is (right of|below) the second"
    ) as info:
        StereoRectifier.from_calibration(calib).rig  # noqa: B018 - the property raises
    return str(info.value)


@pytest.mark.parametrize("rig", [RIGS[0], RIGS[3]], ids=lambda r: r.name)
def test_rig_refusal_names_t_the_convention_and_the_complete_swap(rig: Rig) -> None:
    """A calibration whose first camera is the right (lower) one: the refusal was about 700
    characters, said "swap the calibration's camera 1 and camera 2", which a user did with K
    and D alone (refused the same), and did not name the likeliest cause, a hand-written T of
    the wrong sign. It now gives the T received, OpenCV's convention and the complete swap;
    the remedies it names work, and K and D swapped alone are still refused."""
    i = 1 if rig.name.startswith("v") else 0
    first = ("left", "upper")[i]
    good = StereoRectifier.from_calibration(calib_of(rig)).rig
    # The cameras named the other way: what the calibration of the same rig with camera 1 and
    # camera 2 exchanged is (OpenCV's x2 = R x1 + T).
    named = dataclasses.replace(
        rig, K1=rig.K2, D1=rig.D2, K2=rig.K1, D2=rig.D1, R=rig.R.T, T=-rig.R.T @ rig.T
    )
    message = _refusal(calib_of(named))
    assert "\n" not in message and len(message) < 320, message  # 700 before
    side = ("right of", "below")[i]
    received = "[" + ", ".join(f"{v + 0.0:.6g}" for v in named.T) + "]"
    assert message.startswith(f"the first camera is {side} the second: T = {received} m"), message
    assert f"x2 = R @ x1 + T gives T[{i}] < 0 when the {first} camera is first" in message
    assert "If T's sign is wrong, negate it" in message
    assert "swap K1/K2 and D1/D2 and replace R by R.T, T by -R.T @ T" in message
    assert message.endswith(f"Give the {first} image first")
    # K and D swapped alone: the same R and T, refused the same.
    kd_only = dataclasses.replace(named, K1=named.K2, D1=named.D2, K2=named.K1, D2=named.D1)
    assert _refusal(calib_of(kd_only)) == message
    # The complete swap, as the message gives it, is the rig's own calibration back.
    complete = {"R": named.R.T, "T": -named.R.T @ named.T}
    swapped = dataclasses.replace(kd_only, **complete)
    rig_back = StereoRectifier.from_calibration(calib_of(swapped)).rig
    assert rig_back.baseline_mm == pytest.approx(good.baseline_mm, rel=1e-9)
    assert rig_back.focal_px == pytest.approx(good.focal_px, rel=1e-9)
    # A hand-written T of the wrong sign, the likeliest cause: named, and negating it works.
    flipped = dataclasses.replace(rig, T=-rig.T)
    message = _refusal(calib_of(flipped))
    assert f"T = [{', '.join(f'{v + 0.0:.6g}' for v in flipped.T)}] m" in message, message
    assert flipped.T[i] > 0 and "If T's sign is wrong, negate it" in message
    fixed = StereoRectifier.from_calibration(calib_of(dataclasses.replace(flipped, T=-flipped.T)))
    assert fixed.rig.baseline_mm == pytest.approx(good.baseline_mm, rel=1e-9)


def test_rig_refusal_of_stored_projections_that_disagree_with_t() -> None:
    """A file whose own P1, P2 put the first camera on the right although its T is that of a
    left-first rig: negating T is not the remedy there, and the message does not say it is."""
    rig = RIGS[0]
    r = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T)
    P2 = r.P2.copy()
    P2[0, 3] = -P2[0, 3]
    assert rig.T[0] < 0 and P2[0, 3] > 0
    message = _refusal(calib_of(rig, R1=r.R1, R2=r.R2, P1=r.P1, P2=P2))
    assert message.startswith("the first camera is right of the second in the rectified frame")
    assert "T = [" in message and "its P1, P2 if it holds them" in message
    assert "negate" not in message


def test_rectifier_uses_the_files_transforms_unless_asked() -> None:
    rig = RIGS[1]
    r = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T, alpha=0.3)
    calib = calib_of(rig, R1=r.R1, R2=r.R2, P1=r.P1, P2=r.P2)
    kept = StereoRectifier.from_calibration(calib)
    np.testing.assert_array_equal(kept.P1, r.P1)
    np.testing.assert_allclose(kept.Q, r.Q, rtol=1e-12, atol=1e-12)
    recomputed = StereoRectifier.from_calibration(calib, alpha=1.0)
    assert recomputed.P1[0, 0] != r.P1[0, 0]


def test_rectifier_recomputes_for_zero_disparity_and_fov_scale() -> None:
    # A calibration holding R1, R2, P1, P2 (an OpenCV file from stereoRectify with
    # CALIB_ZERO_DISPARITY, a ROS camera_info pair) kept them when asked for zero_disparity=False
    # or a fov_scale: the option was dropped without a word (P2's cx stayed P1's, the fisheye
    # focal length unscaled, a plumb_bob fov_scale taken). Either option now recomputes.
    rig = RIGS[0]
    args = (rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T)
    r = stereo_rectify(*args)
    calib = calib_of(rig, R1=r.R1, R2=r.R2, P1=r.P1, P2=r.P2, Q=r.Q)
    free = StereoRectifier.from_calibration(calib, zero_disparity=False)
    want = stereo_rectify(*args, zero_disparity=False)
    for got, expected in zip((free.R1, free.R2, free.P1, free.P2, free.Q), want[:5], strict=True):
        np.testing.assert_array_equal(got, expected)
    assert free.P2[0, 2] != free.P1[0, 2]
    with pytest.raises(ValueError, match="balance and fov_scale apply to equidistant"):
        StereoRectifier.from_calibration(calib, fov_scale=1.5)
    fish = dataclasses.replace(
        rig,
        D1=np.array([0.01, -0.002, 0.001, 0.0]),
        D2=np.array([0.012, -0.001, 0.0, 0.0005]),
        model="equidistant",
    )
    fargs = (fish.K1, fish.D1, fish.K2, fish.D2, fish.size, fish.R, fish.T)
    fr = stereo_rectify(*fargs, distortion_model="equidistant")
    fcalib = calib_of(fish, R1=fr.R1, R2=fr.R2, P1=fr.P1, P2=fr.P2, Q=fr.Q)
    scaled = StereoRectifier.from_calibration(fcalib, fov_scale=1.5)
    fwant = stereo_rectify(*fargs, distortion_model="equidistant", fov_scale=1.5)
    np.testing.assert_array_equal(scaled.P1, fwant.P1)
    assert scaled.P1[0, 0] < fr.P1[0, 0]
    # None of them given: the stored transforms, as before.
    np.testing.assert_array_equal(StereoRectifier.from_calibration(calib).P2, r.P2)


@pytest.mark.parametrize("rig_index", [1, 3])  # horizontal, vertical
def test_rectifier_baseline_is_relative_to_p1(rig_index: int) -> None:
    # Projections that place both rectified cameras in a third camera's frame (as KITTI's
    # P0..P3 do: P = K [I | t], t the camera's offset) give the same rig and Q as OpenCV's
    # P1 = [K | 0]: the baseline is P2's translation minus P1's. It used to be P2's alone,
    # so such a file scaled every depth by (t2 - t1) / t2.
    rig = RIGS[rig_index]
    r = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T)
    i = 1 if r.P2[1, 3] != 0 else 0
    offset = np.zeros((3, 4))
    offset[i, 3] = 0.37 * r.P1[0, 0]  # both cameras 0.37 m along the baseline from the origin
    plain = StereoRectifier.from_calibration(calib_of(rig, R1=r.R1, R2=r.R2, P1=r.P1, P2=r.P2))
    moved = StereoRectifier.from_calibration(
        calib_of(rig, R1=r.R1, R2=r.R2, P1=r.P1 + offset, P2=r.P2 + offset)
    )
    assert moved.vertical == plain.vertical == (rig_index == 3)
    assert moved.rig.baseline_mm == pytest.approx(plain.rig.baseline_mm, rel=1e-12)
    assert moved.rig.baseline_mm == pytest.approx(np.linalg.norm(rig.T) * 1000, rel=1e-12)
    np.testing.assert_allclose(moved.Q, plain.Q, rtol=1e-12, atol=1e-12)


def test_rectifier_of_rectified_images_passes_them_through() -> None:
    k = np.array([[1000.0, 0, 600], [0, 1000.0, 180], [0, 0, 1]])
    k2 = k.copy()
    k2[0, 2] = 630.0
    calib = Calib(k, np.zeros(0), k2, np.zeros(0), "none", np.eye(3),
                  np.array([-0.54, 0, 0]), (1241, 376), rectified=True)  # fmt: skip
    rect = StereoRectifier.from_calibration(calib)
    left = np.zeros((376, 1241), np.uint8)
    right = np.ones((376, 1241), np.uint8)
    a, b = rect.rectify(left, right)
    assert a is left and b is right
    sr = rect.rig
    assert (sr.focal_px, sr.doffs_px) == (1000.0, 30.0)
    assert sr.baseline_mm == pytest.approx(540.0)
    with pytest.raises(ValueError, match="left must have the calibration's size"):
        rect.rectify(left[:, :-1], right)
    # Outputs given are written (they used to be left as they were, unnoticed) and checked.
    out_l, out_r = np.full_like(left, 7), np.full_like(right, 7)
    a, b = rect.rectify(left, right, out_left=out_l, out_right=out_r)
    assert a is out_l and b is out_r
    assert np.array_equal(out_l, left) and np.array_equal(out_r, right)
    out_l[:] = 7
    a, b = rect.rectify(left, right, out_left=out_l)
    assert a is out_l and b is right and np.array_equal(out_l, left)
    with pytest.raises(TypeError, match="out_right must have dtype uint8"):
        rect.rectify(left, right, out_right=np.empty(right.shape, np.float32))
    with pytest.raises(ValueError, match=r"out_left must have shape \(376, 1241\)"):
        rect.rectify(left, right, out_left=np.empty((3, 3), np.uint8))


def test_rectifier_from_file_reads_with_calib(tmp_path: Any) -> None:
    calib_module = pytest.importorskip("stereodepth.calib")
    if not hasattr(calib_module, "read_stereo_calibration"):
        pytest.skip("stereodepth.calib.read_stereo_calibration is not on this branch yet")
    # A Middlebury calib.txt: already rectified.
    path = tmp_path / "calib.txt"
    path.write_text(
        "cam0=[1000 0 600; 0 1000 180; 0 0 1]\ncam1=[1000 0 630; 0 1000 180; 0 0 1]\n"
        "doffs=30\nbaseline=540\nwidth=1241\nheight=376\nndisp=128\n"
    )
    rect = StereoRectifier.from_file(path)
    assert rect.rig.focal_px == 1000.0


# --- rejected input ------------------------------------------------------------------------------
def good_args() -> dict[str, Any]:
    rig = RIGS[0]
    return {
        "K1": rig.K1, "D1": rig.D1, "K2": rig.K2, "D2": rig.D2, "image_size": rig.size,
        "R": rig.R, "T": rig.T,
    }  # fmt: skip


@pytest.mark.parametrize(
    ("change", "exc", "match"),
    [
        ({"K1": np.eye(2)}, ValueError, r"K1 must have shape \(3, 3\)"),
        ({"K1": "K"}, TypeError, "K1 must be a real number or array"),
        ({"K2": np.diag([-1.0, 1.0, 1.0])}, ValueError, "K2 must have fx"),
        ({"K1": np.array([[500.0, 1, 320], [0, 500, 240], [0, 0, 1]])}, ValueError, "no skew"),
        ({"K1": np.full((3, 3), np.nan)}, ValueError, "K1 must be finite"),
        ({"D1": np.zeros(6)}, ValueError, "D1 must have 4 or 5 or 8 coefficients"),
        ({"D2": np.zeros((2, 4))}, ValueError, "D2 must be 1-D"),
        ({"image_size": (640,)}, TypeError, "image_size must be a"),
        ({"image_size": (0, 480)}, ValueError, r"image_size\[0\] \(width\) must be"),
        ({"image_size": (640.0, 480)}, TypeError, "must be an integer"),
        ({"R": np.diag([1.0, 1.0, -1.0])}, ValueError, "R must be a rotation matrix"),
        ({"R": 2 * np.eye(3)}, ValueError, "R must be a rotation matrix"),
        ({"T": np.zeros(3)}, ValueError, "T must not be zero"),
        ({"T": np.array([0.01, 0.0, -0.1])}, ValueError, "T must lie mostly across the optical"),
        ({"T": np.zeros(4)}, ValueError, r"T must have shape \(3,\)"),
        ({"alpha": 1.5}, ValueError, "alpha must be -1"),
        ({"alpha": -0.5}, ValueError, "alpha must be -1"),
        ({"alpha": "0"}, TypeError, "alpha must be a real number"),
        ({"new_image_size": (10, -1)}, ValueError, "new_image_size"),
        ({"zero_disparity": 1}, TypeError, "zero_disparity must be a bool, got int 1"),
        ({"zero_disparity": "no"}, TypeError, "zero_disparity must be a bool, got str 'no'"),
        ({"distortion_model": "radtan"}, ValueError, "distortion_model must be one of"),
        ({"distortion_model": 5}, TypeError, "distortion_model must be a str"),
        ({"distortion_model": "equidistant"}, ValueError, "D1 must have 4 coefficients"),
        ({"distortion_model": "none"}, ValueError, "D1 must be empty or zero"),
        ({"balance": 0.5}, ValueError, "balance and fov_scale apply to equidistant"),
        ({"balance": 2.0}, ValueError, r"balance must be in \[0, 1\]"),
        ({"fov_scale": 0.0}, ValueError, "fov_scale must be a finite number > 0"),
        (
            {"distortion_model": "equidistant", "D1": np.zeros(4), "D2": np.zeros(4), "alpha": 0.0},
            ValueError,
            "alpha applies to pinhole models",
        ),
        # Inputs that overflow Bouguet's method gave NaN in P1, then "P must be finite" from
        # the maps of StereoRectifier, naming a matrix the caller never passed.
        (
            {
                "K1": np.diag([1e-298, 1e-298, 1.0])
                + np.array([[0, 0, 320], [0, 0, 240], [0, 0, 0]])
            },
            ValueError,
            r"the calibration gives a non-finite rectification \(P1 = .*fx = 1e-298",
        ),
        (
            {"distortion_model": "equidistant", "D1": [1e10, 0, 0, 0], "D2": np.zeros(4)},
            ValueError,
            r"non-finite rectification .*D1 = \[10000000000\.0, 0\.0, 0\.0, 0\.0\]",
        ),
    ],
)
def test_stereo_rectify_rejects(change: dict[str, Any], exc: type, match: str) -> None:
    args = good_args()
    args.update(change)
    with pytest.raises(exc, match=match):
        stereo_rectify(**args)
    if "non-finite" in match or "zero_disparity" in match:
        # the oracle said "cannot convert float NaN to integer"; it took any zero_disparity
        # for its truth value ("no" as True)
        with pytest.raises(exc, match=match):
            reference.stereo_rectify(**args)


@pytest.mark.parametrize("flag", [np.True_, np.False_])
def test_stereo_rectify_takes_a_numpy_bool_zero_disparity(flag: Any) -> None:
    # numpy's bool (from a mask, a config array) was refused as "zero_disparity must be a
    # bool, got bool"; it is the Python bool of its value, as the matchers' flags are.
    args = good_args()
    want = stereo_rectify(**args, zero_disparity=bool(flag))
    for rectify in (stereo_rectify, reference.stereo_rectify):
        got = rectify(**args, zero_disparity=flag)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("alpha", [0.0, 1.0])
def test_stereo_rectify_names_a_principal_point_on_the_border(alpha: float) -> None:
    # K = diag(f, f, 1) (cx, cy forgotten) puts the principal point on the corner pixel: the
    # alpha scaling divides 0 by 0, as cv2.stereoRectify does (its P1 is NaN). The message
    # blamed the focal lengths, distortion and T, which are fine, and not the principal point.
    args = {
        "K1": np.diag([500.0, 500.0, 1.0]), "D1": None, "K2": np.diag([500.0, 500.0, 1.0]),
        "D2": None, "image_size": (640, 480), "R": np.eye(3), "T": [-0.1, 0.0, 0.0],
    }  # fmt: skip
    match = (
        r"non-finite rectification .*; alpha=.* from the principal point \(cx, cy\), which "
        r"must lie inside the 640 x 480 image: K1's \(0\.0, 0\.0\) and K2's \(0\.0, 0\.0\) "
        r"does not \(a K written without cx, cy\?\)$"
    )
    for rectify in (stereo_rectify, reference.stereo_rectify):
        with pytest.raises(ValueError, match=match):
            rectify(**args, alpha=alpha)
    stereo_rectify(**args)  # alpha=-1 (OpenCV's default scaling) has no such division


def test_stereo_rectify_takes_a_rotation_rounded_in_print(cv2: Any) -> None:
    """An R printed to 6 significant digits (a calibration file, a README) is up to about
    3e-6 from orthonormal: cv2.stereoRectify takes it (its Rodrigues conversion makes it the
    nearest rotation), stereo_rectify refused some with a 1e-6 check; it now takes them within
    1e-5, as the calibration readers do, and gives OpenCV's result."""
    args = good_args()
    rng = np.random.default_rng(0)
    refused_before = 0
    for _ in range(200):
        r = rotation(rng.normal(scale=0.05, size=3))
        r6 = np.array([float(f"{v:.6g}") for v in r.ravel()]).reshape(3, 3)
        refused_before += float(np.abs(r6 @ r6.T - np.eye(3)).max()) > 1e-6
        args["R"] = r6
        ours = stereo_rectify(**args)
        oracle = reference.stereo_rectify(**args)
        theirs = cv2.stereoRectify(
            args["K1"],
            cv_dist(np.asarray(args["D1"])),
            args["K2"],
            cv_dist(np.asarray(args["D2"])),
            args["image_size"],
            r6,
            np.asarray(args["T"], dtype=np.float64).reshape(3, 1),
            alpha=-1,
            flags=cv2.CALIB_ZERO_DISPARITY,
        )
        for a, b, o in zip(ours[:5], theirs[:5], oracle[:5], strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(b).max())
            np.testing.assert_allclose(o, b, rtol=1e-9, atol=1e-9 * np.abs(b).max())
    assert refused_before > 0
    # the maps take such an R1 as given, as cv2.initUndistortRectifyMap does
    r1 = stereo_rectify(**good_args()).R1
    r1_6 = np.array([float(f"{v:.6g}") for v in r1.ravel()]).reshape(3, 3)
    for _ in range(20):
        if float(np.abs(r1_6 @ r1_6.T - np.eye(3)).max()) > 1e-6:
            break
        r1_6 = np.array(
            [float(f"{v:.6g}") for v in (r1_6 + rng.normal(scale=2e-6, size=(3, 3))).ravel()]
        ).reshape(3, 3)
    assert float(np.abs(r1_6 @ r1_6.T - np.eye(3)).max()) > 1e-6
    p1 = stereo_rectify(**good_args()).P1
    size = good_args()["image_size"]
    mx, my = stereodepth.init_undistort_rectify_map(
        good_args()["K1"], good_args()["D1"], r1_6, p1, size
    )
    ox, oy = reference.init_undistort_rectify_map(
        good_args()["K1"], good_args()["D1"], r1_6, p1, size
    )
    cx, cy = cv2.initUndistortRectifyMap(
        good_args()["K1"], cv_dist(np.asarray(good_args()["D1"])), r1_6, p1, size, cv2.CV_32FC1
    )
    np.testing.assert_array_equal(mx, ox)
    np.testing.assert_array_equal(my, oy)
    np.testing.assert_array_equal(mx, cx)  # bit for bit, as for exact rotations
    np.testing.assert_array_equal(my, cy)
    args["R"] = args["R"] + 1e-4
    with pytest.raises(ValueError, match=r"R must be a rotation matrix \(orthonormal within 1e-05"):
        stereo_rectify(**args)


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"image": [[1, 2]]}, TypeError, "image must be a numpy.ndarray"),
        ({"image": np.zeros((4, 4), np.float32)}, TypeError, "image must have dtype uint8"),
        ({"image": np.zeros((4, 4, 3), np.uint16)}, ValueError, r"image must be \(H, W\)"),
        ({"image": np.zeros((4, 4, 4), np.uint8)}, ValueError, r"image must be \(H, W\)"),
        ({"image": np.zeros((0, 4), np.uint8)}, ValueError, "at least one row"),
        ({"map_x": np.zeros((2, 2), np.int32)}, TypeError, "map_x must have dtype float32"),
        ({"map_y": np.zeros((2, 3), np.float32)}, ValueError, "the same shape"),
        ({"map_x": np.zeros(4, np.float32)}, ValueError, "map_x must be 2-D"),
        ({"out": np.zeros((2, 2), np.uint16)}, TypeError, "out must have dtype uint8"),
        ({"out": np.zeros((2, 3), np.uint8)}, ValueError, r"out must have shape \(2, 2\)"),
        ({"threads": -1}, ValueError, "threads must be an integer >= 0"),
        ({"out": "image"}, ValueError, "out must not overlap the image"),
    ],
)
def test_remap_rejects(kwargs: dict[str, Any], exc: type, match: str) -> None:
    args: dict[str, Any] = {
        "image": np.zeros((4, 4), np.uint8),
        "map_x": np.zeros((2, 2), np.float32),
        "map_y": np.zeros((2, 2), np.float32),
    }
    args.update(kwargs)
    if isinstance(args.get("out"), str):  # the image's first 4 pixels, as a 2 x 2 array
        args["out"] = args["image"].reshape(-1)[:4].reshape(2, 2)
    with pytest.raises(exc, match=match):
        stereodepth.remap(**args)


@pytest.mark.parametrize(
    "maps", [stereodepth.init_undistort_rectify_map, reference.init_undistort_rectify_map]
)
@pytest.mark.parametrize(
    ("P", "match"),
    [
        # the kernel said "P @ R must be invertible" without the values
        (
            np.zeros((3, 4)),
            r"^P @ R must be invertible \(its determinant is 0\.0; .*\), got P = "
            r"\[\[0\.0, 0\.0, 0\.0\], .* and R = \[\[1\.0, 0\.0, 0\.0\], ",
        ),
        (np.diag([1e300, 1e300, 1.0]), r"^P @ R must be invertible \(its determinant is inf;"),
        # "must have shape (3, 3)", though a (3, 4) projection is taken too
        (np.eye(4), r"^P must have shape \(3, 3\) or \(3, 4\), got \(4, 4\)$"),
    ],
)
def test_maps_name_the_new_camera_they_cannot_use(maps: Any, P: np.ndarray, match: str) -> None:
    rig = RIGS[0]
    with pytest.raises(ValueError, match=match):
        maps(rig.K1, rig.D1, None, P, (4, 4))


@pytest.mark.parametrize(
    ("K", "D", "model"),
    [
        (np.diag([1e300, 1e300, 1.0]), np.zeros(5), "plumb_bob"),
        (np.array([[700.0, 0, 320], [0, 700, 240], [0, 0, 1]]), [0, 0, 0, 0, 1e38], "plumb_bob"),
        (np.array([[700.0, 0, 320], [0, 700, 240], [0, 0, 1]]), [1e38, 0, 0, 0], "equidistant"),
    ],
)
def test_maps_beyond_float32_are_infinite_in_the_oracle_too(K: Any, D: Any, model: str) -> None:
    # The kernel rounds such positions to +-inf (remap puts them outside the image); the
    # oracle's rounding printed numpy's "overflow encountered in cast" (an error under
    # -W error), so the two could not be compared.
    P = np.array([[650.0, 0, 310, 0], [0, 650, 250, 0], [0, 0, 1, 0]])
    native = stereodepth.init_undistort_rectify_map(K, D, None, P, (8, 6), model)
    oracle = reference.init_undistort_rectify_map(K, D, None, P, (8, 6), model)
    for a, b in zip(native, oracle, strict=True):
        np.testing.assert_array_equal(a, b, strict=True)
    assert np.isinf(native[0]).any()


def _stored(change: dict[str, Any]) -> dict[str, Any]:
    """A calibration's stored transforms (those stereo_rectify computes), with ``change``:
    None drops a P, an int zeroes that row of the P named."""
    rig = RIGS[0]
    r = stereo_rectify(rig.K1, rig.D1, rig.K2, rig.D2, rig.size, rig.R, rig.T)
    kw: dict[str, Any] = {"R1": r.R1, "R2": r.R2, "P1": r.P1.copy(), "P2": r.P2.copy()}
    for key, value in change.items():
        if key in ("P1", "P2") and isinstance(value, int):
            kw[key][value] = 0.0
        else:
            kw[key] = value
    return kw


@pytest.mark.parametrize("rectified", [False, True])
@pytest.mark.parametrize(
    ("change", "match"),
    [
        # A P of zeros (an uncalibrated camera's camera_info) in a calibration object other
        # than StereoCalibration, which checks it: P2's gave ZeroDivisionError ("float
        # division by zero") from Q, P1's a rectifier of garbage maps.
        ({"P2": np.zeros((3, 4))}, r"^calib\.P2 must be a projection .*fx = P\[0, 0\] > 0"),
        ({"P1": np.zeros((3, 4))}, r"^calib\.P1 must be a projection .*got \[\[0\.0, 0\.0"),
        ({"P2": 1}, r"^calib\.P2 must be a projection .*fy = P\[1, 1\] > 0"),
        # a stored Q of zeros came back as rectifier.Q (reproject refused it later, as "Q")
        ({"Q": np.zeros((4, 4))}, r"^calib\.Q must be invertible \(rank 4\), got rank 0"),
    ],
)
def test_rectifier_refuses_a_stored_projection_that_is_none(
    change: dict[str, Any], match: str, rectified: bool
) -> None:
    rig = RIGS[0]
    kw = _stored(change)
    if rectified:  # an already rectified pair keeps P1, P2 and Q only
        kw = {k: v for k, v in kw.items() if k in ("P1", "P2", "Q")}
    with pytest.raises(ValueError, match=match):
        StereoRectifier.from_calibration(calib_of(rig, rectified=rectified, **kw))


def test_maps_and_rectifier_reject() -> None:
    rig = RIGS[0]
    with pytest.raises(ValueError, match=r"P must have shape \(3, 3\)"):
        stereodepth.init_undistort_rectify_map(rig.K1, rig.D1, None, np.eye(4), (4, 4))
    with pytest.raises(ValueError, match="model must be one of"):
        stereodepth.init_undistort_rectify_map(rig.K1, rig.D1, None, rig.K1, (4, 4), "fisheye")
    with pytest.raises(ValueError, match="P @ R must be invertible"):
        stereodepth.init_undistort_rectify_map(rig.K1, rig.D1, None, np.zeros((3, 3)), (4, 4))
    with pytest.raises(TypeError, match="calib must be a StereoCalibration"):
        StereoRectifier.from_calibration(object())
    huge = {**good_args(), "K1": rig.K1 * np.array([[1e300, 1, 1], [1, 1e300, 1], [1, 1, 1]])}
    with pytest.raises(ValueError, match="the calibration gives a non-finite rectification"):
        StereoRectifier(**huge)
    rect = StereoRectifier.from_calibration(calib_of(rig))
    img = np.zeros((rig.size[1], rig.size[0]), np.uint8)
    with pytest.raises(ValueError, match="left and right must have the same shape and dtype"):
        rect.rectify(img, img.astype(np.uint16))
    with pytest.raises(ValueError, match="right must have the calibration's size"):
        rect.rectify(img, img[1:])
    with pytest.raises(ValueError, match="side must be 'left' or 'right'"):
        rect.maps("middle")
    with pytest.raises(ValueError, match="out_right must not overlap the image"):
        rect.rectify(img, img, out_right=img)
    # One array for both outputs, or an output over the other image, was accepted and gave a
    # wrong left (or right) image; the same for a calibration of a rectified pair (copies).
    identity = StereoRectifier.from_calibration(calib_of(rig, rectified=True))
    for r in (rect, identity):
        left, right, out = img.copy(), img.copy(), np.empty_like(img)
        with pytest.raises(ValueError, match="out_right must not overlap out_left"):
            r.rectify(left, right, out_left=out, out_right=out)
        with pytest.raises(ValueError, match="out_left must not overlap right"):
            r.rectify(left, right, out_left=right)
        with pytest.raises(ValueError, match="out_right must not overlap left"):
            r.rectify(left, right, out_right=left[:, :])


def test_plumb_bob_without_coefficients_is_the_pinhole_model() -> None:
    rig = RIGS[5]  # pinhole
    a = stereo_rectify(rig.K1, None, rig.K2, [], rig.size, rig.R, rig.T)
    b = stereo_rectify(rig.K1, None, rig.K2, None, rig.size, rig.R, rig.T, distortion_model="none")
    for x, y in zip(a[:5], b[:5], strict=True):
        np.testing.assert_array_equal(x, y)


def guarded_image(shape: tuple[int, ...], dtype: type, keep: list[Any]) -> np.ndarray:
    """An array whose last byte is the last byte before a PROT_NONE page: reading past the
    image faults. ``keep`` holds the mapping alive."""
    import ctypes
    import mmap

    page = mmap.PAGESIZE
    nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
    data_pages = (nbytes + page - 1) // page
    buf = mmap.mmap(-1, (data_pages + 1) * page)
    libc = ctypes.CDLL(None, use_errno=True)
    addr = ctypes.addressof(ctypes.c_char.from_buffer(buf))
    libc.mprotect.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    if libc.mprotect(ctypes.c_void_p(addr + data_pages * page), page, 0) != 0:
        pytest.skip("mprotect is not available")
    keep.append(buf)
    arr = np.frombuffer(buf, dtype=dtype, count=int(np.prod(shape)),
                        offset=data_pages * page - nbytes)  # fmt: skip
    return arr.reshape(shape)


@pytest.mark.skipif(sys.platform != "linux", reason="uses mmap and mprotect through libc")
@pytest.mark.parametrize("fmt", FORMATS, ids=FORMAT_IDS)
@pytest.mark.parametrize("shape", [(5, 9), (2, 33), (17, 2), (64, 64)])
def test_remap_never_reads_past_the_image(
    fmt: tuple[tuple[int, ...], type], shape: tuple[int, int]
) -> None:
    """The vector path gathers 4 bytes per neighbour pair: at the last row and column it must
    fall back rather than read beyond the image (which here ends at an unreadable page)."""
    extra, dtype = fmt
    keep: list[Any] = []
    img = guarded_image(shape + extra, dtype, keep)
    rng = np.random.default_rng(9)
    img[...] = random_image(rng, shape + extra, dtype)
    h, w = shape
    # Every position near the bottom-right corner, on and between the last pixels.
    ys, xs = np.meshgrid(np.linspace(h - 3, h, 41), np.linspace(w - 3, w, 43), indexing="ij")
    mx, my = xs.astype(np.float32), ys.astype(np.float32)
    got = stereodepth.remap(img, mx, my)
    np.testing.assert_array_equal(got, reference.remap(np.array(img), mx, my))
