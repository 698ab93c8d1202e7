"""stereodepth.metrics.evaluate against an independent pixel-by-pixel count."""

from __future__ import annotations

import math
from dataclasses import FrozenInstanceError

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from stereodepth.metrics import BAD_THRESHOLDS_PX, DisparityMetrics, evaluate

THRESHOLDS = {"bad_0_5": 0.5, "bad_1": 1.0, "bad_2": 2.0, "bad_4": 4.0}


def loop_metrics(d: np.ndarray, g: np.ndarray, mask: np.ndarray | None) -> dict[str, float]:
    """The convention of shared/data/stereo/README.md, one pixel at a time in plain Python."""
    evaluated = 0
    errors: list[float] = []
    truths: list[float] = []
    for y in range(g.shape[0]):
        for x in range(g.shape[1]):
            gt = float(g[y, x])
            if not math.isfinite(gt) or (mask is not None and not mask[y, x]):
                continue
            evaluated += 1
            est = float(d[y, x])
            if math.isfinite(est):
                errors.append(abs(est - gt))
                truths.append(gt)
    holes = evaluated - len(errors)
    out: dict[str, float] = {"evaluated": evaluated, "estimated": len(errors)}
    nan = float("nan")
    out["density"] = len(errors) / evaluated if evaluated else nan
    for key, t in THRESHOLDS.items():
        wrong = sum(1 for e in errors if e > t)
        out[key] = (wrong + holes) / evaluated if evaluated else nan
        out[key + "_est"] = wrong / len(errors) if errors else nan
    # KITTI's D1 (devkit: d_err > 3 and d_err / |d_gt| > 0.05), holes counted as outliers.
    outliers = sum(
        1 for e, gt in zip(errors, truths, strict=True) if e > 3 and (gt == 0 or e / abs(gt) > 0.05)
    )
    out["d1"] = (outliers + holes) / evaluated if evaluated else nan
    out["d1_est"] = outliers / len(errors) if errors else nan
    out["avgerr"] = sum(errors) / len(errors) if errors else nan
    out["rms"] = math.sqrt(sum(e * e for e in errors) / len(errors)) if errors else nan
    return out


def assert_matches(m: DisparityMetrics, want: dict[str, float]) -> None:
    got = m.as_dict()
    assert set(got) == set(want)
    for key, value in want.items():
        if isinstance(value, float) and math.isnan(value):
            assert math.isnan(got[key]), key
        elif key in ("evaluated", "estimated"):
            assert got[key] == value, key
        else:
            assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key


def test_hand_computed_example() -> None:
    nan = np.nan
    gt = np.array([[10.0, 10.0, 10.0, nan], [5.0, 5.0, 5.0, 5.0]], dtype=np.float32)
    d = np.array([[10.25, 11.0, nan, 3.0], [5.0, 9.5, 8.0, 4.0]], dtype=np.float32)
    mask = np.array([[True, True, True, True], [True, True, True, False]])
    m = evaluate(d, gt, mask)
    # evaluated: (0,0) (0,1) (0,2) (1,0) (1,1) (1,2) -> 6; (0,3) has no GT, (1,3) is masked.
    # errors: 0.25, 1.0, hole, 0, 4.5, 3.0 (an error equal to t is not "more than t")
    assert m.evaluated == 6
    assert m.estimated == 5
    assert m.density == pytest.approx(5 / 6)
    assert m.bad_0_5 == pytest.approx(4 / 6)  # 1.0, hole, 4.5, 3.0
    assert m.bad_1 == pytest.approx(3 / 6)  # hole, 4.5, 3.0
    assert m.bad_2 == pytest.approx(3 / 6)
    assert m.bad_4 == pytest.approx(2 / 6)  # hole, 4.5
    assert m.bad_0_5_est == pytest.approx(3 / 5)
    assert m.bad_1_est == pytest.approx(2 / 5)
    assert m.bad_2_est == pytest.approx(2 / 5)
    assert m.bad_4_est == pytest.approx(1 / 5)
    assert m.avgerr == pytest.approx((0.25 + 1.0 + 0 + 4.5 + 3.0) / 5)
    assert m.rms == pytest.approx(math.sqrt((0.0625 + 1.0 + 0 + 20.25 + 9.0) / 5))


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
@pytest.mark.parametrize("with_mask", [False, True])
@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (7, 1), (13, 17)])
def test_random_against_loops(dtype: type, with_mask: bool, shape: tuple[int, int]) -> None:
    rng = np.random.default_rng([*shape, with_mask, np.dtype(dtype).itemsize])
    for _ in range(5):
        gt = rng.uniform(0, 60, shape)
        gt[rng.random(shape) < 0.2] = np.nan
        gt[rng.random(shape) < 0.05] = np.inf
        d = gt + rng.choice([-5.0, -1.5, -0.7, -0.3, 0.0, 0.4, 1.0, 2.0, 3.0, 8.0], shape)
        d[rng.random(shape) < 0.25] = np.nan
        d = d.astype(dtype)
        gt = gt.astype(dtype)
        mask = rng.random(shape) < 0.7 if with_mask else None
        assert_matches(evaluate(d, gt, mask), loop_metrics(d, gt, mask))


@settings(max_examples=60, deadline=None)
@given(
    data=hnp.arrays(
        np.float32,
        st.tuples(st.integers(1, 6), st.integers(1, 6)),
        elements=st.floats(0, 80, width=32) | st.just(np.nan) | st.just(np.inf),
    ),
    noise=st.lists(st.floats(-6, 6, width=32) | st.just(np.nan), min_size=36, max_size=36),
)
def test_property_against_loops(data: np.ndarray, noise: list[float]) -> None:
    d = data + np.array(noise, dtype=np.float32)[: data.size].reshape(data.shape)
    assert_matches(evaluate(d, data), loop_metrics(d, data, None))


def test_perfect_estimate_has_no_bad_pixels() -> None:
    gt = np.random.default_rng(1).uniform(1, 50, (9, 11)).astype(np.float32)
    gt[0, 0] = np.nan
    m = evaluate(gt.copy(), gt)
    assert m.evaluated == 98
    assert m.density == 1.0
    for key in ("bad_0_5", "bad_1", "bad_2", "bad_4", "bad_0_5_est", "bad_4_est"):
        assert getattr(m, key) == 0.0
    assert m.avgerr == 0.0
    assert m.rms == 0.0


def test_all_holes() -> None:
    gt = np.full((4, 5), 7.0, dtype=np.float32)
    m = evaluate(np.full((4, 5), np.nan, dtype=np.float32), gt)
    assert m.evaluated == 20
    assert m.estimated == 0
    assert m.density == 0.0
    assert (m.bad_0_5, m.bad_1, m.bad_2, m.bad_4) == (1.0, 1.0, 1.0, 1.0)
    assert all(math.isnan(v) for v in (m.bad_0_5_est, m.bad_2_est, m.avgerr, m.rms))


def test_infinite_estimate_is_a_hole() -> None:
    gt = np.full((1, 3), 5.0)
    m = evaluate(np.array([[5.0, np.inf, -np.inf]]), gt)
    assert (m.evaluated, m.estimated, m.bad_2, m.bad_2_est) == (3, 1, pytest.approx(2 / 3), 0.0)


def test_nan_gt_is_not_evaluated() -> None:
    gt = np.array([[np.nan, 3.0, np.inf]], dtype=np.float32)
    d = np.array([[100.0, 3.0, 100.0]], dtype=np.float32)
    m = evaluate(d, gt)
    assert (m.evaluated, m.estimated, m.bad_0_5, m.avgerr) == (1, 1, 0.0, 0.0)


def test_negative_ground_truth_is_refused_naming_the_pixel() -> None:
    # A GT of -5 was scored silently (an estimate of 0 counted as 5 px off).
    gt = np.array([[1.0, 2.0, -5.0], [np.nan, -0.5, 3.0]], dtype=np.float32)
    d = np.zeros((2, 3), dtype=np.float32)
    with pytest.raises(
        ValueError,
        match=r"^gt must be >= 0 where it is finite \(KITTI and Middlebury .*\), got -5.0 at row "
        r"0, column 2 \(2 negative pixels\); pass min_disparity < 0",
    ):
        evaluate(d, gt)
    # Only the evaluated pixels count: masked out, the negative values are not scored.
    mask = np.array([[True, True, False], [True, False, True]])
    assert evaluate(d, gt, mask).evaluated == 3
    # -inf is non-finite: unknown, as NaN and inf.
    assert evaluate(d[:1, :2], np.array([[-np.inf, 2.0]], np.float32)).evaluated == 1


def test_negative_ground_truth_with_a_negative_search_range() -> None:
    # A matcher that searched from -8 px: negative true disparities are real. By hand: the
    # estimates -4.5, 1.0, -9 (below -8: a hole) against -5, 1, -7: errors 0.5, 0; one hole.
    gt = np.array([[-5.0, 1.0, -7.0]])
    d = np.array([[-4.5, 1.0, -9.0]])
    m = evaluate(d, gt, min_disparity=-8)
    assert (m.evaluated, m.estimated) == (3, 2)
    assert m.avgerr == pytest.approx(0.25)
    assert m.bad_0_5 == pytest.approx(1 / 3)  # the hole; 0.5 is not more than 0.5
    with pytest.raises(ValueError, match="gt must be >= 0"):
        evaluate(d, gt, min_disparity=0)


def test_huge_errors_do_not_overflow_where_the_result_fits() -> None:
    # By hand: errors 1.7e308 and 0. avgerr = 8.5e307; rms = 1.7e308 / sqrt(2) (the square
    # overflowed, with a RuntimeWarning, an error under -W error).
    m = evaluate(np.array([[1.7e308, 3.0]]), np.array([[1.0, 3.0]]))
    assert m.avgerr == pytest.approx(8.5e307, rel=1e-12)
    assert m.rms == pytest.approx(1.7e308 / math.sqrt(2), rel=1e-12)
    assert (m.bad_4, m.bad_4_est) == (0.5, 0.5)
    # An error beyond a double (-1.7e308 against 1.7e308) is inf, as documented, no warning.
    m = evaluate(np.array([[-1.7e308, 3.0]]), np.array([[1.7e308, 3.0]]))
    assert (m.avgerr, m.rms, m.bad_0_5) == (math.inf, math.inf, 0.5)


def test_min_disparity_beyond_float16_keeps_its_meaning() -> None:
    # -70000 does not fit in float16 (numpy warned "overflow encountered in cast"): nothing
    # finite is below it; +70000: everything is.
    d = np.array([[1.0, -3.0, np.inf]], np.float16)
    gt = np.array([[1.0, 2.0, 2.0]], np.float16)
    low = evaluate(d, gt, min_disparity=-70000)
    assert (low.evaluated, low.estimated, low.avgerr) == (3, 2, pytest.approx(2.5))
    high = evaluate(d, gt, min_disparity=70000)
    assert (high.evaluated, high.estimated, high.bad_0_5) == (3, 0, 1.0)


def test_mask_selects_pixels() -> None:
    gt = np.zeros((2, 2), dtype=np.float32)
    d = np.array([[0.0, 9.0], [np.nan, 0.0]], dtype=np.float32)
    full = evaluate(d, gt)
    assert (full.evaluated, full.bad_1) == (4, 0.5)
    good = evaluate(d, gt, np.array([[True, False], [False, True]]))
    assert (good.evaluated, good.bad_0_5, good.density) == (2, 0.0, 1.0)
    assert evaluate(d, gt, np.array([[False, True], [True, False]])).bad_1 == 1.0


def test_nothing_to_evaluate_gives_nan() -> None:
    gt = np.full((2, 3), np.nan, dtype=np.float32)
    m = evaluate(np.zeros((2, 3), dtype=np.float32), gt)
    assert (m.evaluated, m.estimated) == (0, 0)
    assert all(math.isnan(v) for k, v in m.as_dict().items() if k not in ("evaluated", "estimated"))
    m2 = evaluate(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3), dtype=bool))
    assert m2.evaluated == 0
    assert math.isnan(m2.bad_2)


def test_kitti_d1_needs_both_3_px_and_5_percent() -> None:
    """KITTI's D1: an outlier is off by more than 3 px AND by more than 5 % of the true
    disparity. Hand-made cases on each side of both thresholds; holes count as outliers in
    d1 (as in bad-t) and are left out of d1_est."""
    nan = np.nan
    gt = np.array([[100.0, 50.0, 10.0, 0.0, 80.0, 60.0, 20.0, 30.0]])
    d = np.array([[104.0, 54.0, 12.9, 3.5, 84.0, 63.0, 23.5, nan]])
    # errors:      4 (4 %)  4 (8 %) 2.9   3.5/0  4 (5 %)  3 (5 %) 3.5 (17.5 %)  hole
    # outlier:     no       yes     no    yes    no       no      yes
    m = evaluate(d, gt)
    assert (m.evaluated, m.estimated) == (8, 7)
    assert m.d1_est == 3 / 7
    assert m.d1 == 4 / 8
    want = loop_metrics(d, gt, None)
    assert (want["d1"], want["d1_est"]) == (m.d1, m.d1_est)


def test_result_is_frozen_and_as_dict_is_ordered() -> None:
    m = evaluate(np.zeros((1, 2)), np.ones((1, 2)))
    with pytest.raises(FrozenInstanceError):
        m.bad_2 = 0.0  # type: ignore[misc]
    keys = list(m.as_dict())
    assert keys[:3] == ["evaluated", "estimated", "density"]
    assert keys[-2:] == ["avgerr", "rms"]
    assert BAD_THRESHOLDS_PX == (0.5, 1.0, 2.0, 4.0)
    assert m.as_dict()["bad_0_5"] == 1.0


def test_inputs_are_not_modified() -> None:
    gt = np.array([[1.0, np.nan]], dtype=np.float32)
    d = np.array([[np.nan, 2.0]], dtype=np.float32)
    mask = np.array([[True, True]])
    copies = (gt.copy(), d.copy(), mask.copy())
    evaluate(d, gt, mask)
    np.testing.assert_array_equal(gt, copies[0])
    np.testing.assert_array_equal(d, copies[1])
    np.testing.assert_array_equal(mask, copies[2])


def test_accepts_lists_and_views() -> None:
    gt = np.arange(20, dtype=np.float64).reshape(4, 5)
    d = gt + 1.5
    m = evaluate(d[:, ::2], gt[:, ::2])
    assert (m.evaluated, m.bad_1, m.bad_2) == (12, 1.0, 0.0)
    assert evaluate([[1.0, 2.0]], [[1.0, 5.0]]).bad_2 == 0.5


# One test per rejected input.


def test_rejects_int16_disparity_with_conversion_hint() -> None:
    with pytest.raises(
        TypeError,
        match=r"disparity must be a floating-point .* got dtype int16; "
        r"for OpenCV's fixed-point output \(x16\) pass the matcher's minDisparity as "
        r"min_disparity",
    ):
        evaluate(np.zeros((2, 2), np.int16), np.zeros((2, 2), np.float32))


def test_rejects_uint16_disparity_with_conversion_hint() -> None:
    with pytest.raises(TypeError, match=r"got dtype uint16; KITTI's PNG encoding"):
        evaluate(np.zeros((2, 2), np.uint16), np.zeros((2, 2), np.float32))


def test_rejects_integer_gt() -> None:
    with pytest.raises(TypeError, match=r"^gt must be a floating-point array .*got dtype int32$"):
        evaluate(np.zeros((2, 2), np.float32), np.zeros((2, 2), np.int32))


@pytest.mark.parametrize(
    ("dtype", "hint"),
    [
        (np.uint16, r"; KITTI's PNG encoding must be converted first: .* / 256 with "),
        (np.uint8, r"; Middlebury's 2001-2006 PNGs store d \* s .*d\[raw == 0\] = np.nan$"),
    ],
)
def test_integer_gt_gets_the_datasets_decoding(dtype: type, hint: str) -> None:
    # The datasets' integer ground truth marks unknown pixels with 0: it must be decoded
    # (0 to NaN) before scoring; the message said only "got dtype uint16".
    with pytest.raises(TypeError, match=rf"^gt must be a floating-point array .*{hint}"):
        evaluate(np.zeros((2, 2), np.float32), np.zeros((2, 2), dtype))


def test_rejects_bool_disparity() -> None:
    with pytest.raises(TypeError, match=r"disparity must be .*got dtype bool"):
        evaluate(np.zeros((2, 2), bool), np.zeros((2, 2), np.float32))


def test_rejects_scalar_bool() -> None:
    with pytest.raises(TypeError, match=r"disparity must be a 2-D floating-point array .*got bool"):
        evaluate(True, np.zeros((2, 2), np.float32))


def test_rejects_object_input() -> None:
    with pytest.raises(TypeError, match=r"gt must be a floating-point array .*got dtype <U1"):
        evaluate(np.zeros((1, 1)), [["a"]])


def test_rejects_wrong_ndim() -> None:
    with pytest.raises(ValueError, match=r"^disparity must have shape \(H, W\), got \(2, 2, 3\)$"):
        evaluate(np.zeros((2, 2, 3)), np.zeros((2, 2, 3)))


def test_rejects_1d_gt() -> None:
    with pytest.raises(ValueError, match=r"^gt must have shape \(H, W\), got \(4,\)$"):
        evaluate(np.zeros((2, 2)), np.zeros(4))


def test_rejects_shape_mismatch() -> None:
    with pytest.raises(
        ValueError, match=r"^gt must have the shape of disparity \(3, 4\), got \(3, 5\)$"
    ):
        evaluate(np.zeros((3, 4)), np.zeros((3, 5)))


def test_rejects_non_bool_mask() -> None:
    with pytest.raises(TypeError, match=r"^mask must be a bool array, got dtype uint8$"):
        evaluate(np.zeros((2, 2)), np.zeros((2, 2)), np.ones((2, 2), np.uint8))


def test_rejects_ragged_mask_naming_it() -> None:
    # It got numpy's "setting an array element with a sequence".
    with pytest.raises(ValueError, match=r"^mask must be a rectangular array .* got list "):
        evaluate(np.zeros((2, 2)), np.zeros((2, 2)), [[True, False], [True]])


def test_rejects_mask_shape() -> None:
    with pytest.raises(
        ValueError, match=r"^mask must have the shape of disparity \(2, 2\), got \(2, 3\)$"
    ):
        evaluate(np.zeros((2, 2)), np.zeros((2, 2)), np.ones((2, 3), bool))
