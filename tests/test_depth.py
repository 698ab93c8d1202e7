"""disparity_to_depth: the native kernel against its numpy oracle, and every rejected input."""

from __future__ import annotations

import os
import threading
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import stereodepth
from stereodepth import _core, reference
from stereodepth.depth import DepthOptions

IN_DTYPES = [np.float16, np.float32, np.float64, np.int16, np.uint16]
OUT_DTYPES = [np.float32, np.uint16]
FOCAL_PX, BASELINE_M = 718.856, 0.537166


def special_values(dtype: type) -> np.ndarray:
    """Zero, negatives, the dtype's extremes and, for floats, NaN, infinities, subnormals."""
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        vals = [0, 1, 2, 15, 16, 17, 255, 256, info.max, info.max - 1, info.min, info.min + 1]
        if info.min < 0:
            vals += [-1, -16, -17]
        return np.array(vals, dtype=dtype)
    finfo = np.finfo(dtype)
    vals = [
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
        -finfo.smallest_subnormal,
        finfo.eps,
    ]
    return np.array(vals, dtype=dtype)


def random_disparity(rng: np.random.Generator, dtype: type, shape: tuple[int, ...]) -> np.ndarray:
    """Random plausible disparities with the special values scattered through."""
    if dtype == np.int16:
        a = rng.integers(-40, 16 * 200, size=shape).astype(np.int16)
    elif dtype == np.uint16:
        a = rng.integers(0, 256 * 200, size=shape).astype(np.uint16)
    else:
        a = (rng.random(shape) * 250 - 10).astype(dtype)
    flat = a.reshape(-1)
    sv = special_values(dtype)
    idx = rng.choice(flat.size, size=min(flat.size, 3 * sv.size), replace=False)
    flat[idx] = np.resize(sv, idx.size)
    return a


def default_scale(dtype: type) -> float | None:
    return 1 / 256 if dtype == np.uint16 else None


def assert_same(a: np.ndarray, b: np.ndarray) -> None:
    """Bit-for-bit equality, NaN equal to NaN."""
    assert a.dtype == b.dtype and a.shape == b.shape
    np.testing.assert_array_equal(a, b, strict=True)


@pytest.mark.parametrize("out_dtype", OUT_DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("in_dtype", IN_DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (5, 1023), (2, 4, 33), (1, 1, 1)])
def test_native_matches_oracle(in_dtype: type, out_dtype: type, shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(abs(hash((np.dtype(in_dtype).name, shape))) % 2**32)
    d = random_disparity(rng, in_dtype, shape)
    kw = {
        "focal_px": FOCAL_PX,
        "baseline_m": BASELINE_M,
        "dtype": out_dtype,
        "scale": default_scale(in_dtype),
    }
    assert_same(stereodepth.disparity_to_depth(d, **kw), reference.disparity_to_depth(d, **kw))


@pytest.mark.parametrize("out_dtype", OUT_DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("in_dtype", IN_DTYPES, ids=lambda d: np.dtype(d).name)
def test_every_special_value_matches_oracle(in_dtype: type, out_dtype: type) -> None:
    d = special_values(in_dtype).reshape(1, -1)
    for doffs in (0.0, 31.34, -2.5):
        kw = {
            "focal_px": FOCAL_PX,
            "baseline_m": BASELINE_M,
            "dtype": out_dtype,
            "doffs_px": doffs,
            "scale": default_scale(in_dtype) or 1.0,
        }
        assert_same(stereodepth.disparity_to_depth(d, **kw), reference.disparity_to_depth(d, **kw))


@pytest.mark.parametrize("out_dtype", OUT_DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("in_dtype", IN_DTYPES, ids=lambda d: np.dtype(d).name)
def test_options_match_oracle(in_dtype: type, out_dtype: type) -> None:
    rng = np.random.default_rng(7)
    d = random_disparity(rng, in_dtype, (3, 17, 29))
    for opts in (
        {"min_depth_m": 2.0, "max_depth_m": 30.0},
        {"doffs_px": 53.271, "scale": 0.5},
        {"invalid_value": 0},
        {"min_depth_m": 0.0, "max_depth_m": 5.0, "invalid_value": 1},
    ):
        kw = dict(focal_px=1038.018, baseline_m=0.176252, dtype=out_dtype, **opts)
        kw.setdefault("scale", default_scale(in_dtype))
        assert_same(stereodepth.disparity_to_depth(d, **kw), reference.disparity_to_depth(d, **kw))


@pytest.mark.parametrize("in_dtype", IN_DTYPES, ids=lambda d: np.dtype(d).name)
def test_every_isa_matches_baseline(in_dtype: type) -> None:
    """Each instruction-set variant this CPU runs gives the scalar baseline's bits."""
    rng = np.random.default_rng(11)
    d = random_disparity(rng, in_dtype, (4, 1000))
    args = (
        FOCAL_PX,
        BASELINE_M,
        1.5,
        default_scale(in_dtype) or 1.0,
        0.5,
        100.0,
        None,
        # a hole threshold in raw units: -2 px for OpenCV's int16, 3 px for the others
        {np.int16: -32.0, np.uint16: 768.0}.get(in_dtype, 3.0),
        1,
    )
    for out_dtype in OUT_DTYPES:
        want = np.empty(d.shape, out_dtype)
        _core.disparity_to_depth(d, want, *args, isa="baseline")
        for isa in stereodepth.build_info()["supported_isas"]:
            got = np.empty(d.shape, out_dtype)
            _core.disparity_to_depth(d, got, *args, isa=isa)
            assert_same(got, want)


def test_float32_result_is_within_two_ulp_of_exact() -> None:
    rng = np.random.default_rng(3)
    d = (rng.random((64, 257)) * 300 + 1e-3).astype(np.float32)
    got = stereodepth.disparity_to_depth(
        d, focal_px=FOCAL_PX, baseline_m=BASELINE_M, doffs_px=1.25, scale=0.7
    )
    exact = FOCAL_PX * BASELINE_M / (d.astype(np.float64) * 0.7 + 1.25)
    ulp = np.spacing(exact.astype(np.float32)).astype(np.float64)
    assert np.all(np.abs(got - exact) <= 2 * ulp)


def test_opencv_int16_and_kitti_uint16_conventions() -> None:
    # OpenCV: disparity * 16, holes are (min_disparity - 1) * 16 = -16.
    cv = np.array([[16 * 50, 16 * 50 + 8, -16, 0]], dtype=np.int16)
    z = stereodepth.disparity_to_depth(cv, focal_px=700.0, baseline_m=0.1)
    np.testing.assert_allclose(z[0, :2], [700 * 0.1 / 50, 700 * 0.1 / 50.5], rtol=1e-6)
    assert np.isnan(z[0, 2:]).all()
    # KITTI: disparity * 256, 0 = no data; even with a principal point offset.
    kitti = np.array([[256 * 40, 0, 1]], dtype=np.uint16)
    z = stereodepth.disparity_to_depth(
        kitti, focal_px=700.0, baseline_m=0.5, scale=1 / 256, doffs_px=3.0
    )
    np.testing.assert_allclose(z[0, 0], 700 * 0.5 / 43, rtol=1e-6)
    assert np.isnan(z[0, 1]) and np.isfinite(z[0, 2])


def test_uint16_millimetres_round_half_even_and_clamp() -> None:
    # k / d chosen so that depths land on exact half millimetres.
    d = np.array([[1.0, 2.0, 4.0, 1e-9, 0.0, np.nan]])
    mm = stereodepth.disparity_to_depth(d, focal_px=1.0, baseline_m=0.0025, dtype=np.uint16)
    # 2.5 mm -> 2, 1.25 mm -> 1, 0.625 mm -> 1, huge -> 65535, zero disparity and NaN -> 0.
    np.testing.assert_array_equal(mm, [[2, 1, 1, 65535, 0, 0]])
    mm = stereodepth.disparity_to_depth(
        d, focal_px=1.0, baseline_m=0.0025, dtype=np.uint16, max_depth_m=10.0
    )
    assert mm[0, 3] == 0  # beyond max_depth_m is invalid, not clamped


def uint16_depth_every_way(d: np.ndarray, **kw: Any) -> list[np.ndarray]:
    """Millimetre depth of ``d`` (``kw``: focal_px, baseline_m, scale, min_depth_m) from the
    oracle, disparity_to_depth and the kernel of every instruction set this CPU runs."""
    kw = {"dtype": np.uint16, "scale": None, "min_depth_m": None, **kw}
    got = [reference.disparity_to_depth(d, **kw), stereodepth.disparity_to_depth(d, **kw)]
    o = DepthOptions(
        d,
        focal_px=kw["focal_px"],
        baseline_m=kw["baseline_m"],
        doffs_px=0.0,
        scale=kw["scale"],
        dtype=np.uint16,
        min_depth_m=kw["min_depth_m"],
        max_depth_m=None,
        invalid_value=None,
    )
    for isa in stereodepth.build_info()["supported_isas"]:
        out = np.empty(d.shape, np.uint16)
        args = (o.focal_px, o.baseline_m, o.doffs_px, o.scale, o.min_depth_m, o.max_depth_m)
        _core.disparity_to_depth(d, out, *args, o.invalid_value, o.invalid_below, 1, isa=isa)
        got.append(out)
    return got


def test_uint16_millimetres_keep_a_valid_depth_under_half_a_millimetre() -> None:
    """0 is "no depth" in millimetres: a valid depth that rounded to 0 (0.5 mm or less) was
    written as a hole. It is 1 mm, the nearest valid value, as anything beyond 65.535 m is
    65535; natively, in every instruction set, and in the oracle."""
    # f B = 1e-3 m px: d px is 1 / d mm away.
    mm = [0.0, 0.3, 0.49, 0.5, 0.51, 0.99, 1.0, 1.49, 1.51, 2.49, 1e-300]
    d = np.array([[1.0 / v if v else 1e300 for v in mm] + [0.0, np.nan, -1.0]])
    want = [[1, 1, 1, 1, 1, 1, 1, 1, 2, 2, 1, 0, 0, 0]]
    for got in uint16_depth_every_way(d, focal_px=1.0, baseline_m=1e-3):
        assert got.tolist() == want
    # A depth under min_depth_m is still invalid, not 1 mm; one above it and under 0.5 mm is 1.
    for got in uint16_depth_every_way(d, focal_px=1.0, baseline_m=1e-3, min_depth_m=4e-4):
        assert got.tolist() == [[0, 0, 1, 1, 1, 1, 1, 1, 2, 2, 0, 0, 0, 0]]


@pytest.mark.parametrize("in_dtype", IN_DTYPES, ids=lambda d: np.dtype(d).name)
def test_uint16_millimetres_of_a_tiny_rig_have_no_false_holes(in_dtype: type) -> None:
    """A rig so small that a depth is under half a millimetre (f B = 1e-7 m px) unless its
    disparity is all but 0 (the special values): every such valid pixel is 1 mm, every hole
    0, for every input dtype, and the kernels agree with the oracle bit for bit."""
    rng = np.random.default_rng(5)
    d = random_disparity(rng, in_dtype, (3, 257))
    kw = {"focal_px": 1e-4, "baseline_m": 1e-3, "scale": default_scale(in_dtype)}
    z = stereodepth.disparity_to_depth(d, **{**kw, "dtype": np.float32})
    valid = np.isfinite(z)
    near = valid & (z < 4e-4)
    assert near.mean() > 0.5
    oracle, *native = uint16_depth_every_way(d, **kw)
    assert np.all(oracle[near] == 1) and np.all(oracle[valid] >= 1) and np.all(oracle[~valid] == 0)
    for got in native:
        assert_same(got, oracle)


def test_zero_disparity_is_invalid_and_tiny_is_infinite_and_invalid() -> None:
    d = np.array([[0.0, -0.0, np.float32(1e-45)]], dtype=np.float32)
    z = stereodepth.disparity_to_depth(d, focal_px=1000.0, baseline_m=1.0)
    assert np.isnan(z).all()


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
def test_infinite_disparity_is_invalid_not_zero_metres(dtype: type) -> None:
    """+inf disparity is no match: NaN (0 in millimetres), never a depth of 0 m, natively and
    in the oracle; so is a finite disparity whose d * scale + doffs overflows."""
    d = np.array([[np.inf, -np.inf, np.nan, 10.0]], dtype=dtype)
    for out in (np.float32, np.uint16):
        for fn in (stereodepth.disparity_to_depth, reference.disparity_to_depth):
            z = fn(d, focal_px=1000.0, baseline_m=0.1, dtype=out)
            if out == np.float32:
                assert np.isnan(z[0, :3]).all() and z[0, 3] == np.float32(10.0)
            else:
                assert z.tolist() == [[0, 0, 0, 10000]]
    big = np.array([[np.finfo(np.float32).max]], np.float32)
    z = stereodepth.disparity_to_depth(big, focal_px=1000.0, baseline_m=0.1, scale=16.0)
    assert np.isnan(z).all()


@pytest.mark.parametrize("threads", [1, 2, 3, 5])
def test_thread_count_does_not_change_bits(threads: int) -> None:
    rng = np.random.default_rng(5)
    d = random_disparity(rng, np.float32, (3, 301, 211))
    want = stereodepth.disparity_to_depth(d, focal_px=FOCAL_PX, baseline_m=BASELINE_M, threads=1)
    got = stereodepth.disparity_to_depth(
        d, focal_px=FOCAL_PX, baseline_m=BASELINE_M, threads=threads
    )
    assert_same(got, want)


def test_concurrent_calls_from_python_threads() -> None:
    rng = np.random.default_rng(9)
    inputs = [random_disparity(rng, np.float32, (400, 300)) for _ in range(6)]
    want = [
        reference.disparity_to_depth(d, focal_px=FOCAL_PX, baseline_m=BASELINE_M) for d in inputs
    ]
    results: dict[int, list[np.ndarray]] = {}
    errors: list[BaseException] = []

    def work(i: int) -> None:
        try:
            results[i] = [
                stereodepth.disparity_to_depth(
                    d, focal_px=FOCAL_PX, baseline_m=BASELINE_M, threads=2
                )
                for d in inputs
                for _ in range(5)
            ]
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    workers = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for w in workers:
        w.start()
    for w in workers:
        w.join(timeout=60)
    assert not errors
    for i in range(4):
        for j, got in enumerate(results[i]):
            assert_same(got, want[j // 5])


def test_strided_and_reversed_inputs_are_handled() -> None:
    rng = np.random.default_rng(2)
    base = random_disparity(rng, np.float32, (4, 40, 60))
    for view in (base[:, ::2, :], base[:, :, ::3], base[::-1, ::-1], base[1], base[..., 5:]):
        got = stereodepth.disparity_to_depth(view, focal_px=FOCAL_PX, baseline_m=BASELINE_M)
        want = reference.disparity_to_depth(
            np.ascontiguousarray(view), focal_px=FOCAL_PX, baseline_m=BASELINE_M
        )
        assert_same(got, want)


def test_out_is_filled_in_place_and_returned() -> None:
    d = np.full((5, 6), 10.0, dtype=np.float32)
    out = np.empty((5, 6), dtype=np.uint16)
    res = stereodepth.disparity_to_depth(
        d, focal_px=100.0, baseline_m=0.1, dtype=np.uint16, out=out
    )
    assert res is out and (out == 1000).all()
    # float32 in place: out may be the input itself.
    want = reference.disparity_to_depth(d, focal_px=100.0, baseline_m=0.1)
    res = stereodepth.disparity_to_depth(d, focal_px=100.0, baseline_m=0.1, out=d)
    assert res is d
    assert_same(d, want)


def test_empty_input_gives_empty_output() -> None:
    for shape in [(0, 5), (3, 0), (0, 2, 2)]:
        z = stereodepth.disparity_to_depth(np.zeros(shape, np.float32), focal_px=1, baseline_m=1)
        assert z.shape == shape and z.dtype == np.float32


def test_rig_depth_map_uses_the_rig() -> None:
    rig = stereodepth.StereoRig.from_pixels(baseline_mm=176.252, focal_px=1038.018, doffs_px=53.271)
    d = np.array([[10.0, 60.0]], dtype=np.float32)
    got = rig.depth_map(d)
    want = reference.disparity_to_depth(d, focal_px=1038.018, baseline_m=0.176252, doffs_px=53.271)
    assert_same(got, want)
    np.testing.assert_allclose(got[0], rig.depth_m(np.array([10.0, 60.0])), rtol=1e-6)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0.01, 1e4, allow_nan=False), min_size=2, max_size=40),
    st.floats(1.0, 5000.0),
    st.floats(1e-3, 2.0),
)
def test_depth_decreases_as_disparity_grows(ds: list[float], focal: float, base: float) -> None:
    d = np.sort(np.array(ds, dtype=np.float32))[None, :]
    z = stereodepth.disparity_to_depth(d, focal_px=focal, baseline_m=base)
    finite = z[np.isfinite(z)]
    assert np.all(np.diff(finite) <= 0)


def test_real_kitti_ground_truth_matches_oracle_and_calibration(stereo_scenes) -> None:
    scene = next((s for s in stereo_scenes if s.name.startswith("kitti")), None)
    if scene is None:
        pytest.skip("no KITTI scene in the shared data")
    gt = scene.gt()
    m = scene.meta
    raw = np.where(np.isfinite(gt), np.round(gt * 256), 0).astype(np.uint16)  # KITTI's encoding
    kw = {"focal_px": m["focal_px"], "baseline_m": m["baseline_mm"] / 1000, "scale": 1 / 256}
    for dtype in OUT_DTYPES:
        assert_same(
            stereodepth.disparity_to_depth(raw, dtype=dtype, **kw),
            reference.disparity_to_depth(raw, dtype=dtype, **kw),
        )
    z = stereodepth.disparity_to_depth(
        gt, focal_px=m["focal_px"], baseline_m=m["baseline_mm"] / 1000
    )
    valid = np.isfinite(gt) & (gt > 0)
    np.testing.assert_array_equal(np.isfinite(z), valid)
    np.testing.assert_allclose(
        z[valid], m["focal_px"] * m["baseline_mm"] / 1000 / gt[valid], rtol=1e-6
    )


# --- rejected input: one test per case, type and message checked ---------------------------
GOOD = {"focal_px": 700.0, "baseline_m": 0.1}
D = np.ones((2, 3), np.float32)


@pytest.mark.parametrize(
    ("disparity", "kwargs", "exc", "match"),
    [
        (np.ones((2, 3), np.int32), {}, TypeError, "disparity must have dtype .* got int32"),
        (np.ones((2, 3), np.uint8), {}, TypeError, "got uint8"),
        (np.ones((2, 3), bool), {}, TypeError, "got bool"),
        (np.ones((2, 3), np.complex64), {}, TypeError, "got complex64"),
        (np.ones(5, np.float32), {}, ValueError, r"shape \(H, W\) or \(N, H, W\), got \(5,\)"),
        (np.ones((1, 1, 1, 1), np.float32), {}, ValueError, r"got \(1, 1, 1, 1\)"),
        ("text", {}, TypeError, "disparity must have dtype"),
        # A ragged list got numpy's "setting an array element with a sequence".
        (
            [[1.0, 2.0], [3.0]],
            {},
            ValueError,
            r"^disparity must be a rectangular array .* got list \[\[1.0, 2.0\], \[3.0\]\]$",
        ),
        (D, {"focal_px": 0.0}, ValueError, "focal_px must be a finite number > 0, got 0.0"),
        (D, {"focal_px": -5}, ValueError, "focal_px .* got -5"),
        (D, {"focal_px": float("nan")}, ValueError, "focal_px .* got nan"),
        (D, {"focal_px": float("inf")}, ValueError, "focal_px .* got inf"),
        (D, {"focal_px": "700"}, TypeError, "focal_px must be a real number, got str"),
        (D, {"focal_px": True}, TypeError, "focal_px must be a real number, got bool"),
        # Python's OverflowError "int too large to convert to float", naming nothing.
        (
            D,
            {"focal_px": 10**400},
            ValueError,
            "^focal_px must be within the range of a double .*, got an integer of 401 digits$",
        ),
        (D, {"baseline_m": 0}, ValueError, "baseline_m must be a finite number > 0, got 0"),
        (D, {"baseline_m": None}, TypeError, "baseline_m must be a real number, got NoneType"),
        (D, {"doffs_px": float("nan")}, ValueError, "doffs_px must be finite, got nan"),
        (D, {"scale": -1.0}, ValueError, "scale must be a finite number > 0, got -1.0"),
        (np.ones((2, 3), np.uint16), {}, ValueError, "scale is required for uint16"),
        (D, {"dtype": np.float64}, TypeError, "dtype must be numpy.float32 or numpy.uint16"),
        (D, {"dtype": "nonsense"}, TypeError, "dtype must be numpy.float32 or numpy.uint16"),
        # numpy reads None as float64: the message said "got float64"
        (D, {"dtype": None}, TypeError, "^dtype must be numpy.float32 or numpy.uint16, got None$"),
        (D, {"min_depth_m": -1.0}, ValueError, "min_depth_m must be a finite number >= 0"),
        (D, {"max_depth_m": 0.0}, ValueError, "max_depth_m must be a finite number > 0"),
        (
            D,
            {"min_depth_m": 5.0, "max_depth_m": 1.0},
            ValueError,
            r"max_depth_m must be >= min_depth_m \(5.0\), got 1.0",
        ),
        (D, {"invalid_value": "x"}, TypeError, "invalid_value must be a real number"),
        (D, {"threads": -1}, ValueError, "threads must be an integer >= 0, got -1"),
        (D, {"threads": 1.5}, TypeError, "threads must be an integer, got float"),
        (
            D,
            {"out": np.empty((2, 3), np.float64)},
            TypeError,
            "out must have dtype float32 .* got float64",
        ),
        (
            D,
            {"out": np.empty((3, 2), np.float32)},
            ValueError,
            r"out must have the shape of disparity \(2, 3\), got \(3, 2\)",
        ),
        (D, {"out": np.empty((2, 6), np.float32)[:, ::2]}, TypeError, "out must be C-contiguous"),
        (D, {"out": [[0.0] * 3] * 2}, TypeError, "out must be a numpy.ndarray, got list"),
    ],
)
def test_rejected_input(disparity, kwargs, exc, match) -> None:
    kw = {**GOOD, **kwargs}
    with pytest.raises(exc, match=match):
        stereodepth.disparity_to_depth(disparity, **kw)
    with pytest.raises(exc, match=match):
        reference.disparity_to_depth(disparity, **kw)


@pytest.mark.parametrize(
    ("disparity", "kwargs", "match"),
    [
        # Every pixel was NaN, silently: B*f overflowed a double, or (float32 arithmetic)
        # float32; scale or doffs rounded to 0 or inf in float32.
        (
            D,
            {"focal_px": 1e300, "baseline_m": 1e300},
            r"^focal_px \* baseline_m must be a finite double > 0, got focal_px=1e\+300 and "
            r"baseline_m=1e\+300, whose product is inf$",
        ),
        (D, {"focal_px": 1e-200, "baseline_m": 1e-200}, r"whose product is 0.0$"),
        (
            D,
            {"focal_px": 1e20, "baseline_m": 1e20},
            r"^focal_px \* baseline_m must be within float32's normal range \[1.175e-38, "
            r"3.403e\+38\] \(float32 depth from float32 disparity is computed in float32 "
            r"arithmetic; pass float64 disparity for float64 arithmetic\), got 1e\+40$",
        ),
        (np.ones((2, 3), np.int16), {"scale": 1e-50}, r"^scale must be within float32's .* 1e-50$"),
        (np.ones((2, 3), np.float16), {"doffs_px": 1e39}, r"^doffs_px must be within float32's"),
    ],
)
def test_rig_beyond_the_arithmetic_is_rejected(disparity, kwargs, match) -> None:
    kw = {**GOOD, **kwargs}
    with pytest.raises(ValueError, match=match):
        stereodepth.disparity_to_depth(disparity, **kw)
    with pytest.raises(ValueError, match=match):
        reference.disparity_to_depth(disparity, **kw)


def test_float64_input_takes_what_float32_arithmetic_cannot() -> None:
    # By hand: Z = f B / d = 1e20 * 1e20 / 1e10 = 1e30 m; and 1e40 / 1e30 = 1e10 m.
    d = np.array([[1e10, 1e30]])
    z = stereodepth.disparity_to_depth(d, focal_px=1e20, baseline_m=1e20)
    np.testing.assert_allclose(z, [[1e30, 1e10]], rtol=1e-6)
    # Millimetre output is computed in float64 too: f B = 7 m*px; 7 / 7 = 1 m = 1000 mm, and
    # 7 / 7e-3 = 1000 m, beyond 65.535 m: 65535.
    mm = stereodepth.disparity_to_depth(
        np.array([[7.0, 7e-3]], np.float32), focal_px=7e20, baseline_m=1e-20, dtype=np.uint16
    )
    np.testing.assert_array_equal(mm, [[1000, 65535]])


def test_rejected_read_only_out() -> None:
    out = np.empty((2, 3), np.float32)
    out.flags.writeable = False
    with pytest.raises(ValueError, match="out must be writeable"):
        stereodepth.disparity_to_depth(D, out=out, **GOOD)


def test_rejected_overlapping_out() -> None:
    buf = np.zeros(2 * 3 + 1, np.float32)
    d = buf[:6].reshape(2, 3)
    out = buf[1:].reshape(2, 3)
    with pytest.raises(ValueError, match="out overlaps disparity"):
        stereodepth.disparity_to_depth(d, out=out, **GOOD)
    # Same start, different item size: float16 input read while float32 output is written.
    raw = np.zeros(24, np.uint8)
    with pytest.raises(ValueError, match="out overlaps disparity"):
        stereodepth.disparity_to_depth(
            raw.view(np.float16)[:6].reshape(2, 3), out=raw.view(np.float32).reshape(2, 3), **GOOD
        )


def test_unknown_isa_is_rejected() -> None:
    out = np.empty((2, 3), np.float32)
    with pytest.raises(ValueError, match="isa must be one of"):
        _core.disparity_to_depth(D, out, 1.0, 1.0, 0.0, 1.0, 0.0, 1.0, None, None, 1, isa="sse9")


@pytest.mark.parametrize(
    ("value", "expected"), [("avx-2", None), ("AVX2", None), ("baseline", "baseline")]
)
def test_the_isa_environment_variable_is_checked(value: str, expected: str | None) -> None:
    """A mistyped STEREODEPTH_ISA must not silently run another instruction set: every kernel
    call names the variable and the value (in a fresh process: the choice is made once)."""
    import subprocess
    import sys

    code = (
        "import numpy as np, stereodepth as s\n"
        "try:\n"
        "    s.disparity_to_depth(np.ones((2, 3), np.float32), focal_px=1.0, baseline_m=1.0)\n"
        "    print(s.build_info()['isa'])\n"
        "except ValueError as e:\n"
        "    print('ValueError:', e)\n"
    )
    env = {**os.environ, "STEREODEPTH_ISA": value}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    ).stdout.strip()
    if expected is None:
        assert out.startswith("ValueError:") and "STEREODEPTH_ISA" in out and repr(value) in out
    else:
        assert out == expected


def test_build_info_reports_compiler_isa_and_threads() -> None:
    info = stereodepth.build_info()
    assert info["isa"] in info["supported_isas"]
    assert info["supported_isas"][0] == "baseline"
    assert info["default_threads"] >= 1
    assert info["compiler"] and info["version"] == stereodepth.__version__


def test_arrays_that_went_through_pickle_are_accepted() -> None:
    """Arrays from other processes (multiprocessing, Dask) carry equal but distinct dtypes."""
    import pickle

    d = pickle.loads(pickle.dumps(np.full((3, 4), 8.0, np.float32)))
    out = pickle.loads(pickle.dumps(np.empty((3, 4), np.uint16)))
    for dtype in IN_DTYPES:
        raw = pickle.loads(pickle.dumps(d.astype(dtype)))
        got = stereodepth.disparity_to_depth(raw, scale=1.0, dtype=np.uint16, out=out, **GOOD)
        assert_same(got, reference.disparity_to_depth(raw, scale=1.0, dtype=np.uint16, **GOOD))


@pytest.mark.parametrize("in_dtype", [np.float16, np.float32, np.float64])
@pytest.mark.parametrize("max_depth_m", [3.5e38, 1e300, float(np.finfo(np.float64).max)])
def test_an_infinite_depth_is_beyond_any_max_depth(in_dtype: type, max_depth_m: float) -> None:
    # A max_depth_m beyond float32's range (a user's "no limit") rounded to inf in the float32
    # comparison, so a depth that overflowed float32 (a disparity near 0) came out inf, as a
    # valid depth inside the range; it is above every max_depth_m, and NaN.
    d = np.array([[1.0, 0.0, 2.0, np.finfo(in_dtype).smallest_subnormal]], in_dtype)
    for convert in (stereodepth.disparity_to_depth, reference.disparity_to_depth):
        z = convert(d, focal_px=1e18, baseline_m=1e18, max_depth_m=max_depth_m)
        np.testing.assert_array_equal(z, np.array([[1e36, np.nan, 5e35, np.nan]], np.float32))


@pytest.mark.parametrize("dtype", [np.float32, np.uint16])
@pytest.mark.parametrize("in_dtype", [np.float32, np.float64])
def test_a_min_depth_beyond_float32_without_a_max_names_min_depth(
    dtype: type, in_dtype: type
) -> None:
    # The native check said "max_depth_m must be >= min_depth_m, got 3.40282e+38", of a
    # max_depth_m never given (the oracle gave every pixel invalid); every depth is below it.
    kw = {**GOOD, "min_depth_m": 1e300, "dtype": dtype}
    match = r"^min_depth_m must be at most .*3\.40282.*e\+38.* got 1e\+300"
    for convert in (stereodepth.disparity_to_depth, reference.disparity_to_depth):
        with pytest.raises(ValueError, match=match):
            convert(D.astype(in_dtype), **kw)


@pytest.mark.parametrize(
    "call",
    [
        lambda d: stereodepth.disparity_to_depth(d, **GOOD),
        lambda d: reference.disparity_to_depth(d, **GOOD),
        lambda d: stereodepth.reproject(d, **GOOD),
        lambda d: reference.reproject(d, **GOOD),
        lambda d: stereodepth.to_opencv_disparity(d),
        lambda d: stereodepth.from_opencv_disparity(d.astype(np.int16)),
    ],
    ids=["depth", "depth-oracle", "reproject", "reproject-oracle", "to-opencv", "from-opencv"],
)
def test_a_masked_disparity_is_refused(call: Any) -> None:
    # The mask was dropped: the pixels the user masked (a low confidence, a far range) got a
    # depth or a point from the data beneath, silently.
    d = np.ma.masked_greater(np.array([[1.0, 2.0], [200.0, 4.0]], np.float32), 100)
    with pytest.raises(
        TypeError, match=r"(disparity|raw) must not be a masked array .*\.filled\(numpy\.nan\)"
    ):
        call(d)
