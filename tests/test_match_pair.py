"""stereodepth.match_pair, the steps ``stereodepth match`` and the web page's depth view share,
called from Python: the result is the matcher's and disparity_to_depth's, and bad input is a
TypeError or ValueError naming the parameter and the value received."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import stereodepth as sd
from stereodepth.match_pair import default_num_disparities, match_pair, prepare_pair


def pair() -> tuple[np.ndarray, np.ndarray]:
    left = np.random.default_rng(3).integers(0, 256, (20, 40), dtype=np.uint8)
    return left, np.roll(left, -2, axis=1)


def test_the_result_is_the_matchers_and_the_depth_disparity_to_depths() -> None:
    left, right = pair()
    result = match_pair(left, right, num_disparities=8, focal_px=700.0, baseline_m=0.1)
    disparity, confidence = sd.block_match(left, right, num_disparities=8, return_confidence=True)
    np.testing.assert_array_equal(result.disparity, disparity)
    assert result.confidence is not None
    np.testing.assert_array_equal(result.confidence, confidence)
    assert result.depth is not None
    np.testing.assert_array_equal(
        result.depth, sd.disparity_to_depth(disparity, focal_px=700.0, baseline_m=0.1)
    )


@pytest.mark.parametrize(
    ("left", "right", "exc", "message"),
    [
        # were AttributeError ('list' object has no attribute 'shape') and IndexError (tuple
        # index out of range, from the size message)
        ([[1, 2]], [[1, 2]], TypeError, "left must be a numpy.ndarray image, got list"),
        (np.zeros((4, 5), np.uint8), "b.png", TypeError, "right must be a numpy.ndarray"),
        (
            np.zeros(5, np.uint8),
            np.zeros(6, np.uint8),
            ValueError,
            r"left must be .*got shape \(5,\)",
        ),
        (np.zeros((4, 5), np.uint8), np.array(3, np.uint8), ValueError, r"right .*got shape \(\)"),
    ],
)
def test_prepare_pair_names_the_image_that_is_not_one(
    left: Any, right: Any, exc: type, message: str
) -> None:
    for call in (prepare_pair, match_pair):
        with pytest.raises(exc, match=message):
            call(left, right)


@pytest.mark.parametrize(
    ("rig", "message"),
    [
        ({"focal_px": 700.0}, "focal_px and baseline_m go together: baseline_m missing"),
        ({"baseline_m": 0.1}, "focal_px and baseline_m go together: focal_px missing"),
        ({"doffs_px": 3.0}, "doffs_px applies with focal_px and baseline_m"),
    ],
)
def test_half_a_rig_is_refused(rig: dict[str, Any], message: str) -> None:
    # focal_px without baseline_m (or the other way round) gave no depth without a word.
    left, right = pair()
    with pytest.raises(ValueError, match=message):
        match_pair(left, right, num_disparities=8, **rig)


def test_method_of_another_type_is_a_type_error() -> None:
    left, right = pair()
    with pytest.raises(TypeError, match=r"method must be one of 'bm', 'sgm', got list \['bm'\]"):
        match_pair(left, right, method=["bm"])  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="method must be one of 'bm', 'sgm', got 'BM'"):
        match_pair(left, right, method="BM")


@pytest.mark.parametrize(
    ("width", "exc", "match"),
    [
        # were 16 for -5 and 0, OverflowError ("cannot convert float infinity to integer")
        # for inf and "unsupported operand type(s) for /: 'str' and 'int'" for "640"
        (-5, ValueError, "^width_px must be an integer >= 1, got -5$"),
        (0, ValueError, "^width_px must be an integer >= 1, got 0$"),
        (float("inf"), TypeError, "^width_px must be an integer, got float inf$"),
        ("640", TypeError, "^width_px must be an integer, got str '640'$"),
    ],
)
def test_default_num_disparities_needs_a_width(width: Any, exc: type, match: str) -> None:
    with pytest.raises(exc, match=match):
        default_num_disparities(width)
    assert default_num_disparities(np.int64(640)) == 80
    assert [default_num_disparities(w) for w in (1, 128, 129, 2048, 10**6)] == [
        16,
        16,
        32,
        256,
        256,
    ]
