"""The border band's pixels with no rival (both matchers, border="clip").

Next to the edge a pixel's candidates inside the right image are one to three disparities.
When every one of them lies within one disparity of the winner, nothing tells the winner from
another candidate: at the left edge it is mostly a pixel whose true match has left the right
image (on Piano, columns 0 and 1 were 93 % valid at disparity 0 with confidence 1, where the
true disparity is about 29). Such pixels are NaN, in the kernels of every ISA and in the
oracles alike; a pixel searching its whole range keeps its winner even with
num_disparities <= 3.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from synthetic_pairs import shifted_pair

import stereodepth as sd
from stereodepth import reference as ref

ISAS: list[str] = list(sd.build_info()["supported_isas"])

MATCHERS = {
    "bm": (sd.block_match, ref.block_match, sd.StereoMatcher),
    "sgm": (sd.semi_global_match, ref.semi_global_match, sd.SemiGlobalMatcher),
}

# No filter that would hide the rule (speckle, median, left-right check), so that what the
# second pass decides is what is compared.
BARE = {"lr_max_diff": None, "speckle_window": 0, "uniqueness_ratio": 0}


def unrivalled(d: np.ndarray, x: int, klo: int, n: int, min_d: int) -> np.ndarray:
    """Where column x of d (n candidates klo .. klo + n - 1 inside the image) would have no
    rival: every winner when n <= 2, the middle one (moved at most 0.5 by the fit) when 3."""
    col = d[:, x]
    if n <= 2:
        return np.ones(col.shape, bool)
    return np.abs(col - (min_d + klo + 1)) <= 0.5


def bare(method: str) -> dict[str, Any]:
    kw = dict(BARE)
    if method == "sgm":
        kw["median"] = False
    return kw


@pytest.mark.parametrize("method", sorted(MATCHERS))
@pytest.mark.parametrize("subpixel", [False, True])
def test_first_columns_are_nan_at_the_left_edge(method: str, subpixel: bool) -> None:
    native, oracle, _ = MATCHERS[method]
    left, right = shifted_pair((24, 60), 9, seed=31)
    kw = {"num_disparities": 16, "subpixel": subpixel, "return_confidence": True, **bare(method)}
    d, conf = native(left, right, **kw)
    # Columns 0 and 1: one and two candidates (true disparity 9 lies outside): NaN.
    assert np.isnan(d[:, :2]).all()
    assert (conf[:, :2] == 0).all()
    # Column 2: three candidates; only a winner of 1 (the middle) has no rival.
    col2 = d[:, 2]
    assert np.isnan(col2[np.abs(col2 - 1) <= 0.5]).all()
    # Without the band the pixels were valid: OpenCV's border leaves every column up to 15 NaN,
    # and with the range shifted so that column 0 searches its whole range, it is valid.
    assert np.isnan(native(left, right, **kw, border="opencv")[0][:, :15]).all()
    d_full, _ = native(left, right, **{**kw, "num_disparities": 1})
    assert np.isfinite(d_full[:, 0]).all()
    od, oconf = oracle(left, right, **kw)
    np.testing.assert_array_equal(np.isnan(d), np.isnan(od))
    np.testing.assert_allclose(d, od, rtol=0, atol=1e-3 if subpixel else 0)
    np.testing.assert_allclose(conf, oconf, rtol=0, atol=1e-6)


@pytest.mark.parametrize("method", sorted(MATCHERS))
@pytest.mark.parametrize(("min_d", "nd"), [(-6, 8), (-3, 3), (-1, 2), (2, 5), (0, 3)])
@pytest.mark.parametrize("isa", ISAS)
def test_both_edges_agree_with_the_oracle(method: str, min_d: int, nd: int, isa: str) -> None:
    """A negative min_disparity clips the range at the right edge as well; every ISA's kernel
    gives the oracle's NaNs and values there, with the sub-pixel fit moving middle winners."""
    native, oracle, cls = MATCHERS[method]
    w = 41
    left, right = shifted_pair((17, w), min_d + nd // 2, seed=32 + nd)
    kw = {"num_disparities": nd, "min_disparity": min_d, "return_confidence": True}
    kw.update(bare(method))
    d, conf = cls(isa=isa, threads=2, **kw).compute(left, right)
    od, oconf = oracle(left, right, **kw)
    np.testing.assert_array_equal(np.isnan(d), np.isnan(od))
    np.testing.assert_allclose(d, od, rtol=0, atol=1e-3)
    np.testing.assert_allclose(conf, oconf, rtol=0, atol=1e-6)
    for x in range(w):
        klo, khi = max(0, x - min_d - w + 1), min(nd - 1, x - min_d)
        n = khi - klo + 1
        if n < 1:
            assert np.isnan(d[:, x]).all()
        elif n < nd and n <= 3:
            # the band's least ranges: NaN exactly where the winner has no rival
            lone = unrivalled(od, x, klo, n, min_d) | np.isnan(od[:, x])
            assert np.isnan(d[lone, x]).all()
        elif n == nd:
            # the whole range: the rule never applies (nd <= 3 included)
            assert np.isfinite(d[:, x]).all()
    # The default filters keep the rule: never a valid band pixel without a rival.
    full = native(left, right, num_disparities=nd, min_disparity=min_d)
    np.testing.assert_array_equal(
        np.isnan(full), np.isnan(oracle(left, right, num_disparities=nd, min_disparity=min_d))
    )


@pytest.mark.parametrize("method", sorted(MATCHERS))
@pytest.mark.parametrize("w", [1, 2, 3, 4])
@pytest.mark.parametrize(("min_d", "nd"), [(-2, 6), (-5, 10), (-1, 3), (0, 4)])
def test_images_of_a_few_columns_agree_with_the_oracle(
    method: str, w: int, min_d: int, nd: int
) -> None:
    """An image of at most 3 columns with a negative min_disparity: each pixel's range is
    clipped on both sides to w candidates, away from both edges' columns of the rule."""
    native, oracle, _ = MATCHERS[method]
    big = np.random.default_rng(w * 100 + nd).integers(0, 256, (40, 60), dtype=np.uint8)
    shift = min_d + nd // 2
    left = np.ascontiguousarray(big[:, 20 : 20 + w])
    right = np.ascontiguousarray(big[:, 20 - shift : 20 - shift + w])
    kw = {"num_disparities": nd, "min_disparity": min_d, "return_confidence": True}
    for extra in ({}, bare(method)):
        d, conf = native(left, right, **kw, **extra)
        od, oconf = oracle(left, right, **kw, **extra)
        np.testing.assert_array_equal(np.isnan(d), np.isnan(od))
        np.testing.assert_allclose(d, od, rtol=0, atol=1e-3)
        np.testing.assert_allclose(conf, oconf, rtol=0, atol=1e-6)
        if w <= 2 and w < nd:
            assert np.isnan(d).all()  # every pixel has 1 or 2 candidates: never a rival


@pytest.mark.parametrize("method", sorted(MATCHERS))
@pytest.mark.parametrize("w", [1, 2, 41])
@pytest.mark.parametrize("nd", [1, 5])
def test_a_range_wholly_outside_the_image_is_refused(method: str, w: int, nd: int) -> None:
    """Pixel x is matched at x - d, so only disparities -(w - 1) .. w - 1 can be matched at
    all. A range beyond them on either side (a typo, or a range meant for the uncropped pair)
    is refused by the kernels, the reusable matcher and the oracles alike, naming
    min_disparity and the width; the range that reaches one disparity into the image is
    matched, as the oracle matches it."""
    native, oracle, cls = MATCHERS[method]
    left, right = shifted_pair((9, w), 0, seed=w + nd)
    outside = (w, w + 300, -(w - 1) - nd, -(w - 1) - nd - 300)
    for min_d in outside:
        message = (
            rf"min_disparity={min_d} with num_disparities={nd} searches disparities {min_d} "
            rf"to {min_d + nd - 1}, none of which lies inside an image {w} pixels wide"
        )
        for match in (native, oracle):
            with pytest.raises(ValueError, match=message):
                match(left, right, num_disparities=nd, min_disparity=min_d)
        with pytest.raises(ValueError, match=message):
            cls(num_disparities=nd, min_disparity=min_d).compute(left, right)
    for min_d in (w - 1, -(w - 1) - nd + 1):
        d = native(left, right, num_disparities=nd, min_disparity=min_d)
        od = oracle(left, right, num_disparities=nd, min_disparity=min_d)
        assert d.shape == (9, w)
        np.testing.assert_array_equal(np.isnan(d), np.isnan(od))
        np.testing.assert_allclose(d, od, rtol=0, atol=1e-3)
