"""reproject and write_ply: the native kernel against its numpy oracle and OpenCV, the PLY
files it writes, and every rejected input."""

from __future__ import annotations

import re
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ply_files import read_ply

import stereodepth
from stereodepth import _core, reference
from stereodepth.pointcloud import q_matrix

IN_DTYPES = [np.float16, np.float32, np.float64, np.int16, np.uint16]
ISAS = stereodepth.build_info()["supported_isas"]
RIG = {
    "focal_px": 718.856,
    "baseline_m": 0.537166,
    "cx_px": 607.19,
    "cy_px": 185.22,
    "doffs_px": 0.0,
}
MB_RIG = {
    "focal_px": 1038.018,
    "baseline_m": 0.176252,
    "cx_px": 322.037,
    "cy_px": 243.393,
    "doffs_px": 53.271,
}


def special_values(dtype: type) -> np.ndarray:
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        vals = [0, 1, 2, 15, 16, 17, 255, 256, info.max, info.min]
        if info.min < 0:
            vals += [-1, -16, -17]
        return np.array(vals, dtype=dtype)
    finfo = np.finfo(dtype)
    return np.array(
        [
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.5,
            1e-3,
            np.nan,
            np.inf,
            -np.inf,
            finfo.max,
            -finfo.max,
            finfo.tiny,
            finfo.smallest_subnormal,
            finfo.eps,
        ],
        dtype=dtype,
    )


def random_disparity(rng: np.random.Generator, dtype: type, shape: tuple[int, ...]) -> np.ndarray:
    if dtype == np.int16:
        a = rng.integers(-40, 16 * 200, size=shape).astype(np.int16)
    elif dtype == np.uint16:
        a = rng.integers(0, 256 * 200, size=shape).astype(np.uint16)
    else:
        a = (rng.random(shape) * 250 - 10).astype(dtype)
    flat = a.reshape(-1)
    sv = special_values(dtype)
    idx = rng.choice(flat.size, size=min(flat.size, 2 * sv.size), replace=False)
    flat[idx] = np.resize(sv, idx.size)
    return a


def default_scale(dtype: type) -> float | None:
    return 1 / 256 if dtype == np.uint16 else None


def assert_same(a: np.ndarray, b: np.ndarray) -> None:
    """Bit-for-bit equality, NaN equal to NaN."""
    assert a.dtype == b.dtype and a.shape == b.shape
    np.testing.assert_array_equal(a, b, strict=True)


def random_q(rng: np.random.Generator) -> np.ndarray:
    """A full Q: every entry non-zero, so every product in the kernel matters."""
    q = q_matrix(**RIG) + rng.normal(scale=0.05, size=(4, 4))
    q[3, 2] = abs(q[3, 2]) + 0.5
    return q


# --- native against the oracle ----------------------------------------------------------------
@pytest.mark.parametrize("isa", ISAS)
@pytest.mark.parametrize("in_dtype", IN_DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (5, 1023), (2, 4, 33), (1, 1, 1), (2, 0, 3)])
def test_native_matches_oracle(in_dtype: type, shape: tuple[int, ...], isa: str) -> None:
    rng = np.random.default_rng(abs(hash((np.dtype(in_dtype).name, shape))) % 2**32)
    d = random_disparity(rng, in_dtype, shape) if 0 not in shape else np.zeros(shape, in_dtype)
    for kw in (dict(RIG), dict(MB_RIG), {"Q": random_q(rng)}):
        kw["scale"] = default_scale(in_dtype)
        if "Q" in kw:
            kw["min_disparity"] = -2  # a hole threshold below zero, in pixels
        want = reference.reproject(d, **kw)
        assert_same(stereodepth.reproject(d, **kw), want)
        if d.size == 0:
            continue
        # every instruction set, through the kernel itself
        arr = d.astype(np.float32) if in_dtype == np.float16 else d
        opts = stereodepth.pointcloud.ReprojectOptions(
            d,
            Q=kw.get("Q"),
            focal_px=kw.get("focal_px"),
            baseline_m=kw.get("baseline_m"),
            cx_px=kw.get("cx_px"),
            cy_px=kw.get("cy_px"),
            doffs_px=kw.get("doffs_px"),
            scale=kw["scale"],
            min_depth_m=None,
            max_depth_m=None,
            invalid_value=None,
            min_disparity=kw.get("min_disparity"),
        )
        out = np.empty((*d.shape, 3), np.float32)
        _core.reproject(
            arr,
            out,
            opts.Q,
            opts.scale,
            opts.min_depth_m,
            opts.max_depth_m,
            opts.invalid_value,
            opts.invalid_below,
            0,
            isa,
        )
        assert_same(out, want)


@pytest.mark.parametrize("in_dtype", IN_DTYPES, ids=lambda d: np.dtype(d).name)
def test_options_match_oracle(in_dtype: type) -> None:
    rng = np.random.default_rng(7)
    d = random_disparity(rng, in_dtype, (6, 45))
    cases: list[dict[str, Any]] = [
        {"min_depth_m": 2.0, "max_depth_m": 40.0},
        {"invalid_value": special_values(in_dtype)[4]},
        {"invalid_value": 0.1},  # not a float32: compared in float32 as disparity_to_depth does
        {"doffs_px": -2.5},
        {"cx_px": None, "cy_px": None},
    ]
    for extra in cases:
        kw = {**RIG, "scale": default_scale(in_dtype) or 1.0, **extra}
        assert_same(stereodepth.reproject(d, **kw), reference.reproject(d, **kw))


def test_threads_do_not_change_the_result() -> None:
    d = random_disparity(np.random.default_rng(3), np.float32, (301, 257))
    one = stereodepth.reproject(d, **RIG, threads=1)
    for n in (2, 3, 8, 0, None):
        assert_same(stereodepth.reproject(d, **RIG, threads=n), one)


def test_concurrent_calls_from_python_threads() -> None:
    rng = np.random.default_rng(4)
    inputs = [random_disparity(rng, np.float32, (200, 131)) for _ in range(6)]
    want = [reference.reproject(d, **RIG) for d in inputs]
    got: list[np.ndarray | None] = [None] * len(inputs)

    def work(i: int) -> None:
        for _ in range(5):
            got[i] = stereodepth.reproject(inputs[i], **RIG, threads=2)

    ts = [threading.Thread(target=work, args=(i,)) for i in range(len(inputs))]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    for g, w in zip(got, want, strict=True):
        assert g is not None
        assert_same(g, w)


def test_arrays_that_went_through_pickle() -> None:
    """multiprocessing and Dask hand over arrays whose dtype is equal to numpy's, not it."""
    import pickle

    d = random_disparity(np.random.default_rng(11), np.float32, (9, 14))
    d2 = pickle.loads(pickle.dumps(d))
    out = pickle.loads(pickle.dumps(np.empty((9, 14, 3), np.float32)))
    q = pickle.loads(pickle.dumps(q_matrix(**RIG)))
    assert d2.dtype is not np.dtype(np.float32) and out.dtype is not np.dtype(np.float32)
    assert stereodepth.reproject(d2, Q=q, out=out) is out
    assert_same(out, reference.reproject(d, Q=q_matrix(**RIG)))


def test_non_contiguous_input_and_out() -> None:
    d = random_disparity(np.random.default_rng(5), np.float32, (40, 70))
    view = d[::2, ::3]
    out = np.empty((*view.shape, 3), np.float32)
    r = stereodepth.reproject(view, **RIG, out=out)
    assert r is out
    assert_same(out, reference.reproject(np.ascontiguousarray(view), **RIG))


@pytest.mark.parametrize("in_dtype", IN_DTYPES)
@pytest.mark.parametrize("layout", ["fortran", "broadcast", "reversed", "columns"])
def test_any_layout_of_every_dtype(in_dtype: type, layout: str) -> None:
    # float16 was converted to float32 keeping its layout: a Fortran-order or broadcast
    # float16 map was refused with "disparity must have contiguous rows", which the user did
    # not pass (the other dtypes were copied, as the docstring says).
    d = random_disparity(np.random.default_rng(17), in_dtype, (6, 9))
    view = {
        "fortran": np.asfortranarray(d),
        "broadcast": np.broadcast_to(d[:1], d.shape),
        "reversed": d[::-1, ::-1],
        "columns": d[:, ::2],
    }[layout]
    scale = 1 / 256 if in_dtype == np.uint16 else None
    r = stereodepth.reproject(view, **RIG, scale=scale)
    assert_same(r, reference.reproject(np.ascontiguousarray(view), **RIG, scale=scale))


@pytest.mark.parametrize("max_depth_m", [None, 1e300])
def test_a_point_at_infinite_depth_is_invalid(max_depth_m: float | None) -> None:
    # "A point is invalid where ... a coordinate is not finite": with a max_depth_m beyond
    # float32's range, Z = inf (a disparity whose depth overflows float32) was kept (X = Y = 0
    # here: the pixel is on the principal point).
    d = np.array([[1.0, 1e-300, 2.0]], np.float64)
    for project in (stereodepth.reproject, reference.reproject):
        p = project(d, focal_px=1e5, baseline_m=1e3, cx_px=1.0, cy_px=0.0, max_depth_m=max_depth_m)
        assert np.isnan(p[0, 1]).all() and np.isfinite(p[0, [0, 2]]).all()


@pytest.mark.parametrize("in_dtype", [np.float16, np.float32, np.int16, np.uint16])
@pytest.mark.parametrize("invalid_value", [1e39, -1e300])
def test_an_invalid_value_beyond_float32(in_dtype: type, invalid_value: float) -> None:
    # Compared in float32 it is +-inf; the oracle's cast printed numpy's "overflow encountered
    # in cast" (an error under -W error), so the two could not be compared.
    d = random_disparity(np.random.default_rng(23), in_dtype, (5, 7))
    scale = 1 / 256 if in_dtype == np.uint16 else None
    kw: dict[str, Any] = {**RIG, "scale": scale, "invalid_value": invalid_value}
    assert_same(stereodepth.reproject(d, **kw), reference.reproject(d, **kw))


# --- the geometry -----------------------------------------------------------------------------
def test_points_match_the_closed_forms() -> None:
    rows, cols = 9, 17
    d = np.linspace(1.0, 90.0, rows * cols, dtype=np.float64).reshape(rows, cols)
    f, b, cx, cy, doffs = (
        MB_RIG[k] for k in ("focal_px", "baseline_m", "cx_px", "cy_px", "doffs_px")
    )
    p = stereodepth.reproject(d, **MB_RIG)
    z = f * b / (d + doffs)
    x = (np.arange(cols) - cx) * b / (d + doffs)
    y = (np.arange(rows)[:, None] - cy) * b / (d + doffs)
    np.testing.assert_allclose(p[..., 2], z, rtol=2e-7)
    np.testing.assert_allclose(p[..., 0], x, rtol=2e-7, atol=1e-9)
    np.testing.assert_allclose(p[..., 1], y, rtol=2e-7, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(
    focal=st.floats(100, 3000),
    baseline=st.floats(0.01, 2.0),
    cx=st.floats(-50, 400),
    cy=st.floats(-50, 300),
    doffs=st.floats(-5, 200),
    seed=st.integers(0, 2**32 - 1),
)
def test_points_project_back_to_their_pixel(
    focal: float, baseline: float, cx: float, cy: float, doffs: float, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    d = (rng.random((5, 11)) * 200).astype(np.float32)
    p = stereodepth.reproject(
        d, focal_px=focal, baseline_m=baseline, cx_px=cx, cy_px=cy, doffs_px=doffs
    ).astype(np.float64)
    valid = np.isfinite(p[..., 2])
    np.testing.assert_array_equal(valid, d.astype(np.float64) + doffs > 0)
    u = focal * p[..., 0] / p[..., 2] + cx
    v = focal * p[..., 1] / p[..., 2] + cy
    cols, rows = np.meshgrid(np.arange(11), np.arange(5))
    np.testing.assert_allclose(u[valid], cols[valid], atol=1e-3)
    np.testing.assert_allclose(v[valid], rows[valid], atol=1e-3)
    # and Z is the depth of disparity_to_depth (float64 path)
    z = stereodepth.disparity_to_depth(
        d.astype(np.float64), focal_px=focal, baseline_m=baseline, doffs_px=doffs
    )
    np.testing.assert_allclose(p[..., 2][valid], z[valid], rtol=2e-7)


def test_invalid_pixels_are_nan_in_all_three() -> None:
    d = np.array([[np.nan, 0.0, -3.0, 10.0, np.inf, -np.inf]], np.float32)
    p = stereodepth.reproject(d, **RIG)
    assert np.isnan(p[0, :3]).all() and np.isnan(p[0, 4:]).all()
    assert np.isfinite(p[0, 3]).all()
    # with doffs, d + doffs <= 0 is behind the camera or at infinity
    p = stereodepth.reproject(np.array([[-53.271, -60.0, -50.0]]), **MB_RIG)
    assert np.isnan(p[0, :2]).all() and np.isfinite(p[0, 2]).all()


def test_int16_is_fixed_point_and_negative_is_a_hole() -> None:
    raw = np.array([[160, -16, 0, 8]], np.int16)
    p = stereodepth.reproject(raw, **RIG)
    want = stereodepth.reproject(np.array([[10.0, np.nan, np.nan, 0.5]], np.float32), **RIG)
    assert_same(p, want)


def test_uint16_needs_a_scale_and_zero_is_a_hole() -> None:
    raw = np.array([[2560, 0]], np.uint16)
    with pytest.raises(ValueError, match="scale is required for uint16"):
        stereodepth.reproject(raw, **RIG)
    p = stereodepth.reproject(raw, **RIG, scale=1 / 256)
    assert_same(p, stereodepth.reproject(np.array([[10.0, np.nan]], np.float32), **RIG))


def test_stack_of_frames_is_frame_by_frame() -> None:
    d = random_disparity(np.random.default_rng(6), np.float32, (3, 20, 30))
    stack = stereodepth.reproject(d, **RIG)
    for i in range(3):
        assert_same(stack[i], stereodepth.reproject(d[i], **RIG))


# --- against OpenCV ---------------------------------------------------------------------------
def test_matches_opencv_reproject_image_to_3d() -> None:
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(8)
    d = (rng.random((60, 97)) * 120 + 0.5).astype(np.float32)
    for q in (q_matrix(**RIG), q_matrix(**MB_RIG), random_q(rng)):
        ours = stereodepth.reproject(d, Q=q)
        theirs = cv2.reprojectImageTo3D(d, q)
        ok = np.isfinite(ours).all(axis=-1)
        assert ok.mean() > 0.9
        # OpenCV steps x by adding q_i0 in float64; both round once to float32 at the end.
        scale = np.abs(theirs[ok]).max()
        np.testing.assert_allclose(ours[ok], theirs[ok], rtol=3e-7, atol=scale * 1e-7)
        # where ours is invalid, OpenCV's point is behind the camera or not finite
        bad = ~ok
        assert not (np.isfinite(theirs[bad]).all(axis=-1) & (theirs[bad][:, 2] > 0)).any()


def test_matches_opencv_on_stereobm_output_with_holes_as_nan() -> None:
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(9)
    left = rng.integers(0, 256, (80, 160), dtype=np.uint8)
    right = np.roll(left, -12, axis=1)
    raw = cv2.StereoBM_create(numDisparities=32, blockSize=9).compute(left, right)
    assert (raw < 0).any() and (raw > 0).any()
    q = q_matrix(**RIG)
    ours = stereodepth.reproject(raw, Q=q)  # int16 read as x16, negative = hole
    theirs = cv2.reprojectImageTo3D(raw.astype(np.float32) / 16, q, handleMissingValues=True)
    holes = raw < 0
    assert np.isnan(ours[holes]).all()
    assert (theirs[holes][:, 2] == 10000).all()  # OpenCV's sentinel
    good = raw > 0
    np.testing.assert_allclose(ours[good], theirs[good], rtol=3e-7, atol=1e-5)


# --- real data --------------------------------------------------------------------------------
@pytest.mark.data
def test_ground_truth_point_cloud_of_a_real_scene(stereo_scenes: list[Any]) -> None:
    scene = next((s for s in stereo_scenes if s.name == "mb2014q-adirondack"), None)
    if scene is None:
        pytest.skip("mb2014q-adirondack not in the shared data")
    gt = scene.gt()
    cam0 = np.array(scene.meta["calib"]["cam0"]).reshape(3, 3)
    rig = {
        "focal_px": cam0[0, 0],
        "baseline_m": scene.meta["baseline_mm"] / 1000,
        "cx_px": cam0[0, 2],
        "cy_px": cam0[1, 2],
        "doffs_px": scene.meta["doffs"],
    }
    p = stereodepth.reproject(gt, **rig)
    assert_same(p, reference.reproject(gt, **rig))
    assert_same(np.isnan(p[..., 2]), np.isnan(gt))
    z = stereodepth.disparity_to_depth(
        gt.astype(np.float64),
        focal_px=rig["focal_px"],
        baseline_m=rig["baseline_m"],
        doffs_px=rig["doffs_px"],
    )
    np.testing.assert_allclose(p[..., 2], z, rtol=2e-7)
    # a room-sized scene: 1 to 5 m away
    assert np.nanmin(p[..., 2]) > 1.0 and np.nanmax(p[..., 2]) < 5.0


# --- rejected input ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "exc", "message"),
    [
        ({"Q": np.eye(3)}, ValueError, r"Q must be a 4x4 matrix, got shape \(3, 3\)"),
        ({"Q": np.full((4, 4), np.nan)}, ValueError, "Q must be finite"),
        ({"Q": [["a"] * 4] * 4}, TypeError, "Q must be a 4x4 array of real numbers"),
        # A complex Q lost its imaginary part with only a ComplexWarning; a bool one was 0/1.
        (
            {"Q": np.eye(4) * (1 + 1j)},
            TypeError,
            "Q must be a 4x4 array of real numbers, got dtype complex128",
        ),
        ({"Q": np.eye(4, dtype=bool)}, TypeError, "got dtype bool"),
        ({"Q": np.array([[None] * 4] * 4)}, TypeError, "got dtype object"),
        # A singular Q silently gave every point NaN (W = 0) or flattened the scene.
        ({"Q": np.zeros((4, 4))}, ValueError, r"Q must be invertible \(rank 4\), got rank 0"),
        (
            {"Q": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1], [0, 0, 0, 1]]},
            ValueError,
            r"Q must be invertible \(rank 4\), got rank 3",
        ),
        # The rig's Q overflowed: "Q must be finite, got inf", naming no parameter given.
        (
            {**RIG, "focal_px": 1e300, "baseline_m": 1e300},
            ValueError,
            r"focal_px \* baseline_m must be a finite double > 0 \(an entry of Q\), got "
            r"focal_px=1e\+300 and baseline_m=1e\+300, whose product is inf",
        ),
        (
            {**RIG, "focal_px": 1e-200, "baseline_m": 1e-200},
            ValueError,
            r"focal_px \* baseline_m must be a finite double > 0 .* product is 0.0",
        ),
        (
            {**RIG, "baseline_m": 1e300, "cx_px": 1e10},
            ValueError,
            r"cx_px \* baseline_m must be a finite double \(an entry of Q\), got "
            r"cx_px=10000000000.0",
        ),
        (
            {"Q": np.eye(4), "focal_px": 700.0},
            ValueError,
            "give either Q or focal_px and baseline_m .*, not both; got Q and focal_px",
        ),
        ({"focal_px": 700.0}, ValueError, "needs Q, or focal_px and baseline_m; baseline_m"),
        ({}, ValueError, "needs Q, or focal_px and baseline_m; focal_px and baseline_m missing"),
        ({**RIG, "focal_px": -1.0}, ValueError, "focal_px must be a finite number > 0, got -1.0"),
        ({**RIG, "focal_px": True}, TypeError, "focal_px must be a real number, got bool"),
        ({**RIG, "cx_px": np.nan}, ValueError, "cx_px must be finite, got nan"),
        ({**RIG, "baseline_m": "1"}, TypeError, "baseline_m must be a real number, got str"),
        ({**RIG, "scale": 0.0}, ValueError, "scale must be a finite number > 0, got 0.0"),
        (
            {**RIG, "min_depth_m": 5.0, "max_depth_m": 1.0},
            ValueError,
            r"max_depth_m must be >= min_depth_m \(5.0\), got 1.0",
        ),
        ({**RIG, "threads": -1}, ValueError, "threads must be an integer >= 0, got -1"),
        ({**RIG, "threads": 1.5}, TypeError, "threads must be an integer, got float"),
    ],
)
def test_rejects_bad_options(kwargs: dict[str, Any], exc: type, message: str) -> None:
    with pytest.raises(exc, match=message):
        stereodepth.reproject(np.ones((4, 5), np.float32), **kwargs)


@pytest.mark.parametrize(
    ("disparity", "exc", "message"),
    [
        (
            np.ones((4, 5), np.uint8),
            TypeError,
            "disparity must have dtype float16, float32, float64, int16 .* got uint8",
        ),
        (
            np.ones(5, np.float32),
            ValueError,
            r"must have shape \(H, W\) or \(N, H, W\), got "
            r"\(5,\)",
        ),
        (np.ones((1, 2, 3, 4), np.float32), ValueError, "got \\(1, 2, 3, 4\\)"),
        ("nope", TypeError, "disparity must have dtype"),
    ],
)
def test_rejects_bad_disparity(disparity: Any, exc: type, message: str) -> None:
    with pytest.raises(exc, match=message):
        stereodepth.reproject(disparity, **RIG)


@pytest.mark.parametrize(
    ("out", "exc", "message"),
    [
        (np.empty((4, 5, 3), np.float64), TypeError, "out must have dtype float32, got float64"),
        (
            np.empty((4, 5), np.float32),
            ValueError,
            r"out must have shape \(4, 5, 3\), got \(4, 5\)",
        ),
        (np.empty((4, 5, 6), np.float32)[..., ::2], TypeError, "out must be C-contiguous"),
        ([0.0], TypeError, "out must be a numpy.ndarray, got list"),
    ],
)
def test_rejects_bad_out(out: Any, exc: type, message: str) -> None:
    with pytest.raises(exc, match=message):
        stereodepth.reproject(np.ones((4, 5), np.float32), **RIG, out=out)


def test_rejects_read_only_and_overlapping_out() -> None:
    out = np.empty((4, 5, 3), np.float32)
    out.flags.writeable = False
    with pytest.raises(ValueError, match="out must be writeable"):
        stereodepth.reproject(np.ones((4, 5), np.float32), **RIG, out=out)
    buf = np.ones((4, 5, 3), np.float32)
    with pytest.raises(ValueError, match="out overlaps disparity"):
        stereodepth.reproject(buf[..., 0], **RIG, out=buf)


def test_kernel_rejects_what_the_wrapper_never_sends() -> None:
    out = np.empty((2, 3, 3), np.float32)
    with pytest.raises(
        TypeError, match="disparity must have dtype float32, float64, int16 or uint16, got float16"
    ):
        _core.reproject(np.ones((2, 3), np.float16), out, np.eye(4), 1.0, 0.0, 1.0, None, None, 1)
    with pytest.raises(ValueError, match="Q must be finite"):
        _core.reproject(
            np.ones((2, 3), np.float32), out, np.full((4, 4), np.inf), 1.0, 0.0, 1.0, None, None, 1
        )
    with pytest.raises(ValueError, match="Q must be a 4x4 float64 array"):
        _core.reproject(np.ones((2, 3), np.float32), out, np.eye(3), 1.0, 0.0, 1.0, None, None, 1)
    with pytest.raises(ValueError, match=r"out must have shape \(2, 3\) \+ \(3,\)"):
        _core.reproject(
            np.ones((2, 3), np.float32), out[:1], np.eye(4), 1.0, 0.0, 1.0, None, None, 1
        )
    with pytest.raises(ValueError, match="isa must be one of"):
        _core.reproject(
            np.ones((2, 3), np.float32), out, np.eye(4), 1.0, 0.0, 1.0, None, None, 1, "sse9"
        )


# --- PLY --------------------------------------------------------------------------------------
def test_write_ply_keeps_the_finite_points_with_their_colours(tmp_path: Path) -> None:
    rng = np.random.default_rng(10)
    d = random_disparity(rng, np.float32, (12, 17))
    pts = stereodepth.reproject(d, **RIG)
    rgb = rng.integers(0, 256, (12, 17, 3), dtype=np.uint8)
    path = tmp_path / "cloud.ply"
    n = stereodepth.write_ply(path, pts, rgb, comment="from a test\nsecond line")
    keep = np.isfinite(pts).all(axis=-1)
    assert n == keep.sum() > 0
    header, v = read_ply(path)
    assert "comment from a test" in header and "comment second line" in header
    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], -1), pts[keep])
    np.testing.assert_array_equal(np.stack([v["red"], v["green"], v["blue"]], -1), rgb[keep])
    assert [p.name for p in tmp_path.iterdir()] == ["cloud.ply"]


def test_write_ply_grey_uint16_and_uncoloured(tmp_path: Path) -> None:
    pts = np.array([[0.0, 1.0, 2.0], [np.nan, 0.0, 1.0], [3.0, 4.0, 5.0]], np.float64)
    grey16 = np.array([0x1234, 0xFFFF, 0xAB00], np.uint16)
    assert stereodepth.write_ply(tmp_path / "a.ply", pts, grey16) == 2
    _, v = read_ply(tmp_path / "a.ply")
    assert v["red"].tolist() == v["blue"].tolist() == [0x12, 0xAB]
    assert v["z"].tolist() == [2.0, 5.0]
    assert stereodepth.write_ply(tmp_path / "b.ply", pts) == 2
    header, v = read_ply(tmp_path / "b.ply")
    assert v.dtype.names == ("x", "y", "z")
    assert not any("red" in h for h in header)
    empty = np.full((2, 2, 3), np.nan, np.float32)
    assert stereodepth.write_ply(tmp_path / "c.ply", empty) == 0
    assert read_ply(tmp_path / "c.ply")[1].size == 0


@pytest.mark.parametrize(
    ("points", "colors", "exc", "message"),
    [
        (
            np.zeros((4, 2)),
            None,
            ValueError,
            r"points must have shape \(N, 3\) or \(H, W, 3\), "
            r"got \(4, 2\)",
        ),
        (np.zeros(3), None, ValueError, r"got \(3,\)"),
        (np.array([["a"] * 3]), None, TypeError, "points must be a real array, got dtype <U1"),
        (
            np.zeros((4, 3)),
            np.zeros((4, 3), np.float32),
            TypeError,
            "colors must have dtype uint8 or uint16, got float32",
        ),
        (np.zeros((4, 3)), None, ValueError, "comment must be ASCII text"),
        # A float64 coordinate beyond float32 was cast to inf with a RuntimeWarning and its
        # point silently left out.
        (
            np.array([[0.0, 0.0, 1.0], [1e300, 0.0, 1.0]]),
            None,
            ValueError,
            r"points must fit in float32 .* got a finite coordinate of magnitude 1e\+300",
        ),
        (
            np.zeros((4, 3)),
            np.zeros((5, 3), np.uint8),
            ValueError,
            re.escape(
                "colors must have shape (4,) (grey) or (4, 3) (RGB) to match points, got (5, 3)"
            ),
        ),
    ],
)
def test_write_ply_rejects(
    tmp_path: Path, points: Any, colors: Any, exc: type, message: str
) -> None:
    comment = "déjà vu" if message.startswith("comment") else None
    with pytest.raises(exc, match=message):
        stereodepth.write_ply(tmp_path / "x.ply", points, colors, comment=comment)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("points", "colors", "name"),
    [
        ([[0.0, 0.0, 1.0], [1.0, 2.0]], None, "points"),
        ([[0.0, 0.0, 1.0], [1.0, 2.0, 3.0]], [[1, 2, 3], [4, 5]], "colors"),
    ],
)
def test_write_ply_ragged_list_names_the_parameter(
    tmp_path: Path, points: Any, colors: Any, name: str
) -> None:
    # A ragged list got numpy's "setting an array element with a sequence", naming nothing.
    with pytest.raises(ValueError, match=rf"^{name} must be a rectangular array .* got list \["):
        stereodepth.write_ply(tmp_path / "x.ply", points, colors)
    assert list(tmp_path.iterdir()) == []


def test_write_ply_big_endian_uint16_colours(tmp_path: Path) -> None:
    # They were refused: "colors must have dtype uint8 or uint16, got >u2". By hand, the high
    # bytes of 7 * 256 + 9, 0 and 65535 are 7, 0 and 255.
    path = tmp_path / "be.ply"
    colors = np.array([[7 * 256 + 9, 0, 65535]], ">u2")
    assert stereodepth.write_ply(path, np.array([[1.0, 2.0, 3.0]], ">f8"), colors) == 1
    _, vertex = read_ply(path)
    assert [int(vertex[k][0]) for k in ("red", "green", "blue")] == [7, 0, 255]
    assert [float(vertex[k][0]) for k in ("x", "y", "z")] == [1.0, 2.0, 3.0]


def test_write_ply_takes_python_lists(tmp_path: Path) -> None:
    path = tmp_path / "l.ply"
    assert stereodepth.write_ply(path, [[0.5, -1.0, 2.0], [1.0, 2.0, 3.0]]) == 2
    assert stereodepth.write_ply(path, [[0.5, -1.0, 2.0]], np.array([[1, 2, 3]], np.uint8)) == 1


@pytest.mark.parametrize("comment", [5, b"bytes", ["a", "b"]])
def test_write_ply_comment_not_text(tmp_path: Path, comment: Any) -> None:
    # A wrong type was a ValueError (the rule of the package: TypeError for a wrong type).
    with pytest.raises(TypeError, match=r"comment must be a str, got "):
        stereodepth.write_ply(tmp_path / "x.ply", np.zeros((4, 3)), comment=comment)
    assert list(tmp_path.iterdir()) == []
