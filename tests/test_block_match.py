"""stereodepth.block_match / StereoMatcher against the numpy oracle, and its rules.

The oracle (stereodepth.reference.block_match) follows the documented steps with a full cost
volume; the kernel must agree exactly on integer disparities and validity, and within 1e-3 px
after the sub-pixel step. Images are small so the oracle stays fast.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from synthetic_pairs import shifted_pair, slanted_pair

import stereodepth as sd
from stereodepth import _core
from stereodepth import reference as ref
from stereodepth._reference_block_match import grey
from stereodepth.io import read_image

SUPPORTED_ISAS: list[str] = list(sd.build_info()["supported_isas"])


# ------------------------------------------------------------------------------------------
# Test images


def assert_agree(native: Any, oracle: Any, *, subpixel: bool) -> None:
    """The same NaNs; equal disparities (within 1e-3 px after the sub-pixel step)."""
    if isinstance(oracle, tuple):
        assert isinstance(native, tuple)
        assert_agree(native[0], oracle[0], subpixel=subpixel)
        np.testing.assert_allclose(native[1], oracle[1], rtol=0, atol=1e-6)
        return
    assert native.dtype == np.float32
    assert native.shape == oracle.shape
    np.testing.assert_array_equal(np.isnan(native), np.isnan(oracle))
    if subpixel:
        np.testing.assert_allclose(native, oracle, rtol=0, atol=1e-3)
    else:
        np.testing.assert_array_equal(native, oracle)


# Parameter sets that exercise every step; each is compared with the oracle.
CONFIGS: list[dict[str, Any]] = [
    {"subpixel": False, "uniqueness_ratio": 0, "lr_max_diff": None},
    {"subpixel": False},
    {},
    {"cost": "sad"},
    {"cost": "sad", "subpixel": "parabola", "block_size": 5},
    {"subpixel": "parabola", "return_confidence": True},
    {"block_size": 3, "uniqueness_ratio": 25, "lr_max_diff": 0},
    {"block_size": 15, "texture_threshold": 8.0, "lr_max_diff": 2.5},
    {"speckle_window": 30, "speckle_range": 0.5, "return_confidence": True},
    {"cost": "sad", "texture_threshold": 3.0, "uniqueness_ratio": 2.5, "return_confidence": True},
]


def config_id(cfg: dict[str, Any]) -> str:
    return ",".join(f"{k}={v}" for k, v in cfg.items()) or "defaults"


def subpixel_of(cfg: dict[str, Any]) -> bool:
    return cfg.get("subpixel", True) is not False


# ------------------------------------------------------------------------------------------
# Native against the oracle


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("cfg", CONFIGS, ids=config_id)
def test_random_dots_match_oracle(cfg: dict[str, Any], isa: str) -> None:
    left, right = shifted_pair((31, 77), 6, seed=1)
    # Some flat and some repeated texture: ties, and work for the validity checks.
    left[5:15, 20:40] = 128
    right[5:15, 14:34] = 128
    left[20:28, 40:70] = np.tile(np.array([0, 0, 255, 255], np.uint8), 8)[:30]
    right[20:28, 34:64] = np.tile(np.array([0, 0, 255, 255], np.uint8), 8)[:30]
    kw = {"num_disparities": 21, "min_disparity": -3, **cfg}
    native = sd.StereoMatcher(isa=isa, **kw).compute(left, right)
    assert_agree(native, ref.block_match(left, right, **kw), subpixel=subpixel_of(cfg))


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("cost", ["census", "sad"])
def test_ties_go_to_the_lowest_disparity(isa: str, cost: str) -> None:
    # A flat pair costs the same at every disparity; a pattern of period 4 ties every 4 px.
    kw: dict[str, Any] = {
        "num_disparities": 11,
        "min_disparity": -2,
        "cost": cost,
        "subpixel": False,
        "uniqueness_ratio": 0,
        "lr_max_diff": None,
    }
    flat = np.full((9, 30), 77, np.uint8)
    d = sd.StereoMatcher(isa=isa, **kw).compute(flat, flat)
    assert (d[:, 8:28] == -2).all()
    row = np.tile(np.array([10, 200, 60, 130], np.uint8), 10)
    stripes = np.repeat(row[None, :], 9, axis=0)
    left = np.ascontiguousarray(stripes[:, 0:30])
    right = np.ascontiguousarray(stripes[:, 3:33])  # shift 3, and -1 and 7 (period 4)
    d = sd.StereoMatcher(isa=isa, **kw).compute(left, right)
    np.testing.assert_array_equal(d[:, 12:22], -1.0)
    np.testing.assert_array_equal(d, ref.block_match(left, right, **kw))


@pytest.mark.parametrize("cfg", CONFIGS, ids=config_id)
def test_slanted_plane_matches_oracle(cfg: dict[str, Any]) -> None:
    left, right, _ = slanted_pair((26, 90), d0=4.3, dx=0.09, dy=0.05, seed=2)
    kw = {"num_disparities": 19, **cfg}
    assert_agree(
        sd.block_match(left, right, **kw),
        ref.block_match(left, right, **kw),
        subpixel=subpixel_of(cfg),
    )


def test_slanted_plane_is_recovered_to_subpixel_accuracy() -> None:
    left, right, disp = slanted_pair((40, 120), d0=6.2, dx=0.05, dy=0.02, seed=3)
    est = sd.block_match(left, right, num_disparities=24, block_size=7)
    good = np.isfinite(est)
    assert good.mean() > 0.6
    err = np.abs(est - disp)[good]
    assert np.median(err) < 0.25
    assert (err < 1).mean() > 0.95


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("cost", ["census", "sad"])
def test_dtypes_match_oracle(dtype: Any, cost: str) -> None:
    left, right = shifted_pair((20, 60), 4, seed=4, dtype=dtype)
    kw = {"num_disparities": 12, "cost": cost, "return_confidence": True}
    assert_agree(
        sd.block_match(left, right, **kw), ref.block_match(left, right, **kw), subpixel=True
    )


def test_rgb_matches_oracle_and_is_matched_as_its_grey() -> None:
    left, right = shifted_pair((20, 50), 5, seed=5, rgb=True)
    kw: dict[str, Any] = {"num_disparities": 10, "return_confidence": True}
    native = sd.block_match(left, right, **kw)
    assert_agree(native, ref.block_match(left, right, **kw), subpixel=True)
    gl, gr = grey(left).astype(np.uint8), grey(right).astype(np.uint8)
    grey_result = sd.block_match(gl, gr, **kw)
    np.testing.assert_array_equal(native[0], grey_result[0])
    np.testing.assert_array_equal(native[1], grey_result[1])


def test_grey_conversion_is_opencvs() -> None:
    cv2 = pytest.importorskip("cv2")
    rgb = np.random.default_rng(6).integers(0, 256, (17, 23, 3)).astype(np.uint8)
    np.testing.assert_array_equal(grey(rgb), cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


@pytest.mark.parametrize("order", ["rgb", "bgr"])
@pytest.mark.parametrize("isa", sd.build_info()["supported_isas"])
def test_native_grey_conversion_is_the_oracles_for_every_colour(isa: str, order: str) -> None:
    # Every one of the 2^24 colours, then every width from 1 to 70 (the SIMD loop's tails). A
    # B, G, R image is converted as it is: its grey is that of the reversed (R, G, B) copy.
    every = np.arange(1 << 24, dtype=np.uint32)
    rgb = np.stack([every >> 16, (every >> 8) & 255, every & 255], axis=-1).astype(np.uint8)
    rgb = rgb.reshape(4096, 4096, 3)

    def want(img: np.ndarray) -> np.ndarray:
        return np.asarray(grey(img[..., ::-1] if order == "bgr" else img)).astype(np.uint8)

    np.testing.assert_array_equal(_core._rgb_to_grey(rgb, isa, order), want(rgb))
    rng = np.random.default_rng(8)
    for w in range(1, 71):
        img = rng.integers(0, 256, (3, w, 3)).astype(np.uint8)
        np.testing.assert_array_equal(_core._rgb_to_grey(img, isa, order), want(img))


@pytest.mark.parametrize("isa", sd.build_info()["supported_isas"])
def test_bgr_pair_is_matched_as_its_reversed_copy(isa: str) -> None:
    # B, G, R pairs go to the kernels as they are (no reversed copy): the same disparity and
    # confidence as the R, G, B pair, for both matchers, with widths around the SIMD step.
    for w in (17, 18, 33, 50):
        left, right = shifted_pair((20, w), 3, seed=w, rgb=True)
        bl, br = np.ascontiguousarray(left[..., ::-1]), np.ascontiguousarray(right[..., ::-1])
        for make in (sd.StereoMatcher, sd.SemiGlobalMatcher):
            kw: dict[str, Any] = {"num_disparities": 8, "return_confidence": True, "isa": isa}
            a = make(**kw).compute(left, right)
            b = make(**kw, channel_order="bgr").compute(bl, br)
            np.testing.assert_array_equal(a[0], b[0])
            np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.parametrize(
    ("rgb", "error"),
    [
        (np.zeros((4, 5, 3), np.uint16), TypeError),
        (np.zeros((4, 5, 3), np.float32), TypeError),
        (np.zeros((4, 5), np.uint8), ValueError),
        (np.zeros((4, 5, 4), np.uint8), ValueError),
        (np.zeros((0, 5, 3), np.uint8), ValueError),
        (np.zeros((4, 0, 3), np.uint8), ValueError),
    ],
)
def test_native_grey_conversion_names_what_it_takes(rgb: np.ndarray, error: type) -> None:
    with pytest.raises(error, match=r"rgb must be \(H, W, 3\) uint8.*got shape"):
        _core._rgb_to_grey(rgb)


@pytest.mark.parametrize("cost", ["census", "sad"])
def test_sixteen_bit_image_of_an_eight_bit_one_matches_the_same(cost: str) -> None:
    # uint16 pairs are stretched from their joint range onto 0..65280 (= 255 * 256) and SAD
    # shifts their Sobel response by 8 bits: x256 of a uint8 pair changes nothing.
    left, right = shifted_pair((18, 48), 3, seed=7)
    kw = {"num_disparities": 9, "cost": cost}
    a = sd.block_match(left, right, **kw)
    b = sd.block_match(left.astype(np.uint16) * 256, right.astype(np.uint16) * 256, **kw)
    np.testing.assert_array_equal(a, b)


@pytest.mark.data
def test_scene_crops_match_oracle(stereo_scenes: list[Any]) -> None:
    pytest.importorskip("PIL.Image", reason="reading the scenes needs Pillow (the batch extra)")
    for scene in stereo_scenes:
        left = read_image(scene.left_path)
        right = read_image(scene.right_path)
        h, w = left.shape[:2]
        y0, x0 = h // 2 - 20, w // 2 - 60
        lc = np.ascontiguousarray(left[y0 : y0 + 40, x0 : x0 + 150])
        rc = np.ascontiguousarray(right[y0 : y0 + 40, x0 : x0 + 150])
        for cfg in ({"return_confidence": True}, {"cost": "sad", "subpixel": "parabola"}):
            kw = {"num_disparities": 48, **cfg}
            assert_agree(sd.block_match(lc, rc, **kw), ref.block_match(lc, rc, **kw), subpixel=True)


# ------------------------------------------------------------------------------------------
# Shapes that break tails


@pytest.mark.parametrize(
    ("shape", "nd", "md"),
    [
        ((1, 40), 8, 0),  # a single row
        ((3, 1), 1, 0),  # a single column
        ((12, 7), 3, 0),  # narrow, odd
        ((9, 10), 16, 0),  # width smaller than num_disparities: all NaN
        ((10, 33), 1, 0),  # one disparity
        ((10, 33), 2, -1),  # two disparities, no second-best
        ((11, 45), 33, -5),  # lanes beyond one vector
        ((13, 70), 17, -20),  # all negative disparities
        ((6, 1023), 31, 2),  # wide, odd
    ],
)
@pytest.mark.parametrize("cfg", [{}, {"return_confidence": True, "cost": "sad"}], ids=config_id)
def test_tail_shapes_match_oracle(
    shape: tuple[int, int], nd: int, md: int, cfg: dict[str, Any]
) -> None:
    left, right = shifted_pair(shape, max(md, 0) + nd // 2, seed=8)
    kw = {"num_disparities": nd, "min_disparity": md, **cfg}
    assert_agree(
        sd.block_match(left, right, **kw), ref.block_match(left, right, **kw), subpixel=True
    )


def test_many_disparities_take_the_generic_path() -> None:
    # More than 256 disparities: the AVX-512 build leaves its register-resident pass.
    left, right = shifted_pair((8, 330), 270, seed=9)
    kw: dict[str, Any] = {"num_disparities": 290, "block_size": 5, "return_confidence": True}
    assert_agree(
        sd.block_match(left, right, **kw), ref.block_match(left, right, **kw), subpixel=True
    )


def test_width_smaller_than_num_disparities_is_all_nan_with_opencvs_border() -> None:
    left, right = shifted_pair((14, 12), 2, seed=10)
    assert np.isnan(sd.block_match(left, right, num_disparities=13, border="opencv")).all()
    # Clipped, every column has candidates inside the image: matched, but for columns 0 and 1,
    # whose one or two candidates leave the winner no rival more than one disparity away.
    # (14 rows: the region of the other columns stays above the speckle filter's 100 px.)
    d = sd.block_match(left, right, num_disparities=13, subpixel=False)
    assert np.isnan(d[:, :2]).all()
    assert np.isfinite(d[3:-3, 4:-2]).all()


def test_search_range_leaving_the_image_is_nan_with_opencvs_border() -> None:
    left, right = shifted_pair((16, 60), 5, seed=11)
    kw: dict[str, Any] = {
        "num_disparities": 10,
        "min_disparity": -4,
        "subpixel": False,
        "uniqueness_ratio": 0,
        "lr_max_diff": None,
    }
    d = sd.block_match(left, right, border="opencv", **kw)
    # x - d must lie in [0, 60) for every d in [-4, 5]: columns 5 .. 55.
    assert np.isnan(d[:, :5]).all()
    assert np.isnan(d[:, 56:]).all()
    assert np.isfinite(d[:, 5:56]).all()
    np.testing.assert_array_equal(d, ref.block_match(left, right, border="opencv", **kw))


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("cfg", CONFIGS, ids=config_id)
def test_border_band_is_matched_over_the_disparities_inside_the_image(
    isa: str, cfg: dict[str, Any]
) -> None:
    # The default border="clip": the left columns are matched over the candidates whose right
    # pixel lies in the image; here the shift 5 is among them from column 5 on.
    left, right = shifted_pair((24, 70), 5, seed=12)
    kw: dict[str, Any] = {"num_disparities": 24, "min_disparity": -2, **cfg}
    native = sd.StereoMatcher(isa=isa, **kw).compute(left, right)
    assert_agree(native, ref.block_match(left, right, **kw), subpixel=subpixel_of(cfg))
    d = native[0] if isinstance(native, tuple) else native
    opencv = sd.StereoMatcher(isa=isa, border="opencv", **kw).compute(left, right)
    d_cv = opencv[0] if isinstance(opencv, tuple) else opencv
    assert np.isnan(d_cv[:, :21]).all()
    np.testing.assert_array_equal(d[:, 21:68], d_cv[:, 21:68])
    if cfg.get("subpixel", True) is False and not cfg.get("texture_threshold"):
        assert (d[6:-6, 9:21] == 5).mean() > 0.9
    # No winner ever lies outside the image.
    x = np.arange(70)
    assert (d[np.isfinite(d)] <= np.broadcast_to(x, d.shape)[np.isfinite(d)] + 2).all()


def test_border_is_rejected_when_unknown() -> None:
    with pytest.raises(ValueError, match="border must be 'clip' or 'opencv', got 'zero'"):
        sd.block_match(*shifted_pair((8, 20), 2, seed=1), num_disparities=4, border="zero")
    with pytest.raises(TypeError, match="border must be 'clip' or 'opencv', got int 0"):
        sd.StereoMatcher(num_disparities=4, border=0)  # type: ignore[arg-type]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    shift=st.integers(-6, 12),
    md=st.integers(-8, 4),
    nd=st.integers(9, 24),
    bs=st.sampled_from([3, 5, 9]),
    seed=st.integers(0, 2**16),
)
def test_shifted_random_dots_give_the_shift(
    shift: int, md: int, nd: int, bs: int, seed: int
) -> None:
    if not md <= shift <= md + nd - 1:
        shift = md + (shift - md) % nd
    w = 64
    left, right = shifted_pair((12, w), shift, seed=seed)
    d = sd.block_match(
        left, right, num_disparities=nd, min_disparity=md, block_size=bs, subpixel=False
    )
    # Away from the borders (search range, block and census window inside the image) the
    # cost at the shift is 0 and every other disparity costs more.
    r = bs // 2 + 2
    x0 = max(md + nd - 1, 0) + r + max(shift, 0)
    x1 = min(w - 1 + md, w - 1) - r - max(-shift, 0)
    if x1 >= x0:
        np.testing.assert_array_equal(d[:, x0 : x1 + 1], np.float32(shift))
    d_sub = sd.block_match(left, right, num_disparities=nd, min_disparity=md, block_size=bs)
    if x1 >= x0:
        assert np.all(np.abs(d_sub[:, x0 : x1 + 1] - shift) <= 0.5)


# ------------------------------------------------------------------------------------------
# Limits: the largest blocks on 16-bit images with costs near their maximum


@pytest.mark.parametrize(("cost", "bs"), [("census", 63), ("sad", 31)])
def test_largest_block_sizes_do_not_overflow(cost: str, bs: int) -> None:
    rng = np.random.default_rng(12)
    right = rng.integers(0, 65536, (bs + 4, 70)).astype(np.uint16)
    left = (65535 - right).astype(np.uint16)  # inverted: costs near the maximum everywhere
    kw: dict[str, Any] = {
        "num_disparities": 6,
        "cost": cost,
        "block_size": bs,
        "uniqueness_ratio": 0,
        "lr_max_diff": None,
        "return_confidence": True,
    }
    assert_agree(
        sd.block_match(left, right, **kw), ref.block_match(left, right, **kw), subpixel=True
    )


def test_block_size_limits_are_exported() -> None:
    assert sd.matching.MAX_BLOCK_SIZE == {"census": 63, "sad": 31}
    for cost, bs in sd.matching.MAX_BLOCK_SIZE.items():
        assert bs * bs * sd.matching.PIXEL_COST_MAX[cost] < 0xFFFF
        assert (bs + 2) ** 2 * sd.matching.PIXEL_COST_MAX[cost] >= 0xFFFF


# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("min_disparity", [-40, -9])
def test_right_border_band_winners_on_the_range_edge_match_oracle(
    isa: str, min_disparity: int
) -> None:
    # Negative disparities: the search ranges of the right columns leave the right image on
    # their low side. On unrelated noise many winners fall on the lowest candidate inside the
    # image, whose neighbour outside the range must read as "none" and leave the disparity
    # integral (border_band's rule). The uniqueness check stays on (a tiny ratio), as the
    # SIMD passes take their fastest path only with it.
    rng = np.random.default_rng(31)
    left = rng.integers(0, 256, (23, 97), dtype=np.uint8)
    right = rng.integers(0, 256, (23, 97), dtype=np.uint8)
    kw: dict[str, Any] = {
        "num_disparities": 48,
        "min_disparity": min_disparity,
        "uniqueness_ratio": 0.01,
        "lr_max_diff": None,
        "speckle_window": 0,
    }
    native = sd.StereoMatcher(isa=isa, **kw).compute(left, right)
    assert_agree(native, ref.block_match(left, right, **kw), subpixel=True)
    np.testing.assert_array_equal(
        native, sd.StereoMatcher(isa="baseline", **kw).compute(left, right)
    )
    # The case this test is for occurs: integral winners on the lowest candidate of a clipped
    # range, in the band where the range is clipped.
    x = np.arange(97)
    low = np.maximum(x - 96, min_disparity)  # the least disparity whose right pixel is inside
    band = x - 96 > min_disparity
    on_edge = (native == low) & band
    assert on_edge.sum() >= 3


# Instruction sets and threads


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize(
    "cfg",
    [
        {"num_disparities": 37, "min_disparity": -3, "return_confidence": True},
        {"num_disparities": 64, "cost": "sad", "subpixel": "parabola", "texture_threshold": 2},
        {"num_disparities": 5, "speckle_window": 10, "return_confidence": True},
        {"num_disparities": 160, "block_size": 13},
        {"num_disparities": 270, "block_size": 5, "return_confidence": True},
    ],
    ids=config_id,
)
def test_each_isa_matches_the_scalar_path(isa: str, cfg: dict[str, Any]) -> None:
    left, right, _ = slanted_pair((37, 301), d0=20.0, dx=0.03, dy=0.1, seed=13)
    scalar = sd.StereoMatcher(isa="baseline", **cfg).compute(left, right)
    simd = sd.StereoMatcher(isa=isa, **cfg).compute(left, right)
    if isinstance(scalar, tuple):
        for a, b in zip(scalar, simd, strict=True):
            np.testing.assert_array_equal(a, b)
    else:
        np.testing.assert_array_equal(scalar, simd)


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
def test_each_isa_on_odd_shapes(isa: str) -> None:
    for shape, nd, md in [((1, 1), 1, 0), ((5, 3), 2, -1), ((9, 65), 33, 0), ((4, 97), 64, -7)]:
        left, right = shifted_pair(shape, nd // 2 + md, seed=14)
        for cfg in ({"return_confidence": True}, {"cost": "sad", "return_confidence": True}):
            kw = {"num_disparities": nd, "min_disparity": md, **cfg}
            scalar = sd.StereoMatcher(isa="baseline", **kw).compute(left, right)
            simd = sd.StereoMatcher(isa=isa, **kw).compute(left, right)
            for a, b in zip(scalar, simd, strict=True):
                np.testing.assert_array_equal(a, b)


# Disparity ranges that reach every fixed-size first pass of the SIMD builds (16 lanes a
# vector, up to 256 disparities, in the AVX2 and AVX-512 builds alike), with and without
# padding lanes, and two beyond them (the generic pass).
FIXED_PASS_RANGES = [16 * k - (k % 4) * 3 for k in range(1, 17)] + [9, 264]
FIXED_PASS_CONFIGS: list[dict[str, Any]] = [
    {},
    {"return_confidence": True, "subpixel": "parabola", "min_disparity": -2},
    {"lr_max_diff": None, "subpixel": False, "uniqueness_ratio": 0, "texture_threshold": 4.0},
    {"lr_max_diff": 0, "uniqueness_ratio": 15, "block_size": 5},
    # The border band's groups (from min_disparity on) in the defaults' two-pixel loop, at the
    # largest block whose costs << 4 fit signed lanes, and the first beyond it.
    {"min_disparity": 7, "uniqueness_ratio": 5, "block_size": 11},
    {"min_disparity": 3, "block_size": 13},
]


@pytest.mark.parametrize("isa", [isa for isa in SUPPORTED_ISAS if isa != "baseline"])
@pytest.mark.parametrize("cost", ["census", "sad"])
@pytest.mark.parametrize("nd", FIXED_PASS_RANGES)
def test_each_fixed_pass_matches_the_scalar_path(isa: str, cost: str, nd: int) -> None:
    left, right, _ = slanted_pair((21, 120 + nd), d0=0.6 * nd, dx=0.02, dy=0.1, seed=nd)
    # A flat patch (ties) and a repeated one (work for the uniqueness check).
    left[3:12, 10:40] = 90
    right[3:12, 10:40] = 90
    left[12:20, 50:82] = np.tile(np.array([0, 0, 255, 255], np.uint8), 8)
    right[12:20, 50:82] = np.tile(np.array([0, 0, 255, 255], np.uint8), 8)
    for cfg in FIXED_PASS_CONFIGS:
        kw = {"num_disparities": nd, "cost": cost, **cfg}
        scalar = sd.StereoMatcher(isa="baseline", **kw).compute(left, right)
        simd = sd.StereoMatcher(isa=isa, **kw).compute(left, right)
        if isinstance(scalar, tuple):
            for a, b in zip(scalar, simd, strict=True):
                np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_array_equal(scalar, simd)
        # Not a vacuous comparison: many pixels with a full search range are matched.
        disparity = scalar[0] if isinstance(scalar, tuple) else scalar
        assert np.isfinite(disparity[:, nd:]).mean() > 0.25


def test_unknown_isa_is_rejected() -> None:
    with pytest.raises(ValueError, match="isa must be one of"):
        sd.StereoMatcher(num_disparities=8, isa="sse9")


@pytest.mark.parametrize(
    "cfg", [{}, {"cost": "sad", "return_confidence": True, "block_size": 21}], ids=config_id
)
def test_thread_counts_give_identical_output(cfg: dict[str, Any]) -> None:
    left, right, _ = slanted_pair((131, 90), d0=9.0, dx=0.02, dy=0.05, seed=15)
    outs = [sd.block_match(left, right, num_disparities=24, threads=t, **cfg) for t in (1, 2, 3)]
    for other in outs[1:]:
        if isinstance(other, tuple):
            for a, b in zip(outs[0], other, strict=True):
                np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_array_equal(outs[0], other)


def test_oversubscribed_threads_give_identical_output() -> None:
    # More threads than cores: workers get descheduled, finish at different times and steal
    # rows from each other, so the row pieces (and the speckle filter's joins) vary from run
    # to run; the output must not.
    left, right, _ = slanted_pair((240, 120), d0=9.0, dx=0.03, dy=0.02, seed=18)
    kw: dict[str, Any] = {"num_disparities": 24, "return_confidence": True}
    want = sd.block_match(left, right, threads=1, **kw)
    for threads in (5, 7, 16):
        for _ in range(3):
            got = sd.block_match(left, right, threads=threads, **kw)
            for a, b in zip(want, got, strict=True):
                np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_speckle_regions_across_bands_match_oracle(threads: int) -> None:
    # Noise blobs of every size on a slanted plane: regions cross the bands' borders.
    left, right, _ = slanted_pair((96, 64), d0=8.0, dx=0.05, dy=0.02, seed=16)
    rng = np.random.default_rng(17)
    for _ in range(40):
        y, x = rng.integers(0, 90), rng.integers(20, 58)
        h, w = rng.integers(1, 7, size=2)
        left[y : y + h, x : x + w] = rng.integers(0, 256, size=(min(h, 96 - y), min(w, 64 - x)))
    for window, spread in [(40, 0.5), (200, 2.0)]:
        kw: dict[str, Any] = {
            "num_disparities": 16,
            "speckle_window": window,
            "speckle_range": spread,
            "return_confidence": True,
        }
        native = sd.block_match(left, right, threads=threads, **kw)
        assert_agree(native, ref.block_match(left, right, **kw), subpixel=True)


def test_concurrent_calls_from_python_threads() -> None:
    pairs = [slanted_pair((40, 80), d0=5.0 + i, dx=0.01, dy=0.0, seed=20 + i)[:2] for i in range(6)]
    kw: dict[str, Any] = {"num_disparities": 16, "threads": 2, "return_confidence": True}
    serial = [sd.block_match(lft, rgt, **kw) for lft, rgt in pairs]
    shared = sd.StereoMatcher(**kw)
    barrier = threading.Barrier(4)

    def work(i: int) -> tuple[Any, Any]:
        if i < 4:
            barrier.wait(timeout=60)
        lft, rgt = pairs[i % len(pairs)]
        return sd.block_match(lft, rgt, **kw), shared.compute(lft, rgt)

    with ThreadPoolExecutor(max_workers=4) as pool:
        results = list(pool.map(work, range(12)))
    for i, (own, via_shared) in enumerate(results):
        want = serial[i % len(pairs)]
        for a, b, c in zip(want, own, via_shared, strict=True):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(a, c)


# ------------------------------------------------------------------------------------------
# StereoMatcher and the output format


def test_matcher_reuses_its_buffers_across_sizes() -> None:
    m = sd.StereoMatcher(num_disparities=12, return_confidence=True)
    for shape, seed in [((30, 70), 30), ((12, 200), 31), ((30, 70), 32), ((5, 13), 33)]:
        left, right = shifted_pair(shape, 4, seed=seed)
        got = m.compute(left, right)
        want = sd.block_match(left, right, num_disparities=12, return_confidence=True)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)


def test_thread_matcher_is_kept_per_thread_and_parameters() -> None:
    from stereodepth._methods import thread_matcher

    first = thread_matcher("bm", num_disparities=12, block_size=7)
    assert thread_matcher("bm", block_size=7, num_disparities=12) is first  # order: no matter
    assert first.params["block_size"] == 7
    other = thread_matcher("bm", num_disparities=12, block_size=9)
    assert other is not first and other.params["block_size"] == 9
    assert thread_matcher("bm", num_disparities=12, block_size=9) is other
    with ThreadPoolExecutor(max_workers=1) as pool:
        elsewhere = pool.submit(thread_matcher, "bm", num_disparities=12, block_size=9).result()
    assert elsewhere is not other
    left, right = shifted_pair((20, 50), 3, seed=40)
    np.testing.assert_array_equal(
        other.compute(left, right), sd.block_match(left, right, num_disparities=12)
    )


def test_one_shot_keeps_the_threads_matcher_and_still_checks_every_call(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """block_match reuses the calling thread's matcher while the parameters stay the same (so
    a loop of calls costs what StereoMatcher.compute does), yet a value that equals a valid
    one but has a type the checks refuse (16.0 for 16, 1 for True) is refused every time."""
    from stereodepth import _methods

    left, right = shifted_pair((20, 50), 3, seed=41)
    first = sd.block_match(left, right, num_disparities=16)
    kept = _methods._thread_state.matcher[1]
    again = sd.block_match(left, right, num_disparities=16)
    assert _methods._thread_state.matcher[1] is kept
    np.testing.assert_array_equal(first, again)
    with pytest.raises(TypeError, match=r"num_disparities must be an integer, got float 16\.0"):
        sd.block_match(left, right, num_disparities=16.0)
    with pytest.raises(TypeError, match="subpixel must be True, False"):
        sd.block_match(left, right, num_disparities=16, subpixel=1)
    np.testing.assert_array_equal(
        sd.block_match(left, right, num_disparities=16),
        sd.StereoMatcher(num_disparities=16).compute(left, right),
    )
    other = sd.block_match(left, right, num_disparities=16, block_size=5)
    assert _methods._thread_state.matcher[1] is not kept  # new parameters: a new matcher
    np.testing.assert_array_equal(
        other, sd.StereoMatcher(num_disparities=16, block_size=5).compute(left, right)
    )
    # A pair above the size limit is not kept (its buffers would stay held).
    from stereodepth import matching

    monkeypatch.setattr(matching, "KEEP_MATCHER_MAX_PIXELS", 20 * 50 - 1)
    sd.block_match(left, right, num_disparities=16)
    assert _methods._thread_state.matcher is None


@pytest.mark.parametrize("match", [sd.block_match, sd.semi_global_match])
@pytest.mark.parametrize("refused", [(True, 4095), (1.0, 4095), [1, np.float64(4095)]])
def test_one_shot_checks_the_items_of_intensity_range_every_call(match: Any, refused: Any) -> None:
    # The kept matcher was found by comparing the values with == and only their outer type:
    # after (1, 4095), an intensity_range of (True, 4095) or (1.0, 4095), which the checks
    # refuse, equalled the kept key and was matched with, or refused, by the thread's history.
    left, right = (a.astype(np.uint16) * 16 for a in shifted_pair((12, 30), 2, seed=42))
    valid = type(refused)([1, 4095])  # of the same outer type: tuple or list
    kept = match(left, right, num_disparities=8, intensity_range=valid)
    assert np.isfinite(kept).any()
    with pytest.raises(TypeError, match="intensity_range must be None or two integers"):
        match(left, right, num_disparities=8, intensity_range=refused)


@pytest.mark.parametrize("match", [sd.block_match, sd.semi_global_match])
def test_one_shot_follows_a_list_edited_in_place(match: Any) -> None:
    # The kept matcher's key held the caller's intensity_range list itself: edited in place
    # between two calls, it still equalled the key, and the second call matched with the old
    # range (and skipped the checks of the new one).
    rng = np.random.default_rng(7)
    left = rng.integers(0, 4096, (40, 60)).astype(np.uint16)
    right = np.roll(left, -3, axis=1)
    ranges = [0, 65535]
    match(left, right, num_disparities=8, intensity_range=ranges)
    ranges[1] = 1000
    edited = match(left, right, num_disparities=8, intensity_range=ranges)
    fresh = match(left, right, num_disparities=8, intensity_range=(0, 1000))
    wide = match(left, right, num_disparities=8, intensity_range=(0, 65535))
    assert not np.array_equal(fresh, wide, equal_nan=True)  # the two ranges differ here
    np.testing.assert_array_equal(edited, fresh)
    ranges[0] = 70000
    with pytest.raises(ValueError, match="intensity_range"):
        match(left, right, num_disparities=8, intensity_range=ranges)


def test_matcher_params_and_repr() -> None:
    m = sd.StereoMatcher(num_disparities=32, block_size=7, lr_max_diff=None)
    p = m.params
    assert p["num_disparities"] == 32
    assert p["block_size"] == 7
    assert p["lr_max_diff"] is None
    assert p["subpixel"] in ("parabola", "equiangular")
    assert repr(m).startswith("StereoMatcher(num_disparities=32")
    assert "isa=" not in repr(m)
    assert sd.StereoMatcher(num_disparities=4, subpixel=False).params["subpixel"] is False
    # The repr makes the same matcher, the instruction set it was made for included.
    pinned = sd.StereoMatcher(num_disparities=32, block_size=7, isa="baseline")
    assert repr(pinned).endswith(", isa='baseline')")
    again = eval(repr(pinned), {"StereoMatcher": sd.StereoMatcher})
    assert again.params == pinned.params and again.isa == "baseline"


def test_inputs_are_not_modified_and_views_are_accepted() -> None:
    left, right = shifted_pair((20, 80), 3, seed=34)
    lc, rc = left.copy(), right.copy()
    d1 = sd.block_match(left[:, ::2], right[:, ::2], num_disparities=6)  # non-contiguous
    d2 = sd.block_match(
        np.ascontiguousarray(left[:, ::2]), np.ascontiguousarray(right[:, ::2]), num_disparities=6
    )
    np.testing.assert_array_equal(d1, d2)
    np.testing.assert_array_equal(left, lc)
    np.testing.assert_array_equal(right, rc)


def test_confidence_is_in_unit_interval_and_zero_on_holes() -> None:
    left, right, _ = slanted_pair((30, 80), d0=5.0, dx=0.05, dy=0.0, seed=35)
    d, c = sd.block_match(left, right, num_disparities=16, return_confidence=True)
    assert c.dtype == np.float32
    assert ((c >= 0) & (c <= 1)).all()
    assert (c[np.isnan(d)] == 0).all()
    # The uniqueness check is a threshold on the confidence.
    d10 = sd.block_match(left, right, num_disparities=16, uniqueness_ratio=10)
    d0, c0 = sd.block_match(
        left, right, num_disparities=16, uniqueness_ratio=0, return_confidence=True
    )
    away = np.abs(c0.astype(np.float64) - 10 / 110) > 1e-6  # float32 rounding at the edge
    np.testing.assert_array_equal(np.isfinite(d10)[away], (np.isfinite(d0) & (c0 > 10 / 110))[away])


def test_to_opencv_disparity() -> None:
    d = np.array([[0.0, 1.5, np.nan], [2.03125, 63.9375, -0.5]], dtype=np.float32)
    # -0.5 px is valid only when the search range reaches it: with min_disparity 0, OpenCV
    # would read its -8 as a hole, so it is refused rather than lost.
    with pytest.raises(ValueError, match=r">= min_disparity \(0\) px or NaN"):
        sd.to_opencv_disparity(d)
    out = sd.to_opencv_disparity(d, min_disparity=-1)
    assert out.dtype == np.int16
    np.testing.assert_array_equal(out, [[0, 24, -32], [33, 1023, -8]])
    out = sd.to_opencv_disparity(d, min_disparity=-4)
    assert out[0, 2] == -80
    # Round trip through the depth converter's OpenCV convention.
    assert np.allclose(out[np.isfinite(d)] / 16, d[np.isfinite(d)], atol=1 / 32)


# ------------------------------------------------------------------------------------------
# Rejected input: one test per rule

GOOD = shifted_pair((8, 20), 2, seed=40)


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        (
            {"num_disparities": 0},
            ValueError,
            r"num_disparities must be an integer in \[1, 4096\], got 0",
        ),
        (
            {"num_disparities": 4097},
            ValueError,
            r"num_disparities must be an integer in \[1, 4096\], got 4097",
        ),
        ({"num_disparities": 1.5}, TypeError, "num_disparities must be an integer, got float 1.5"),
        ({"num_disparities": True}, TypeError, "num_disparities must be an integer, got bool"),
        ({"num_disparities": None}, TypeError, "num_disparities must be an integer, got NoneType"),
        (
            {"num_disparities": 8, "min_disparity": 40000},
            ValueError,
            r"min_disparity must be an integer in \[-32768, 32768\], got 40000",
        ),
        (
            {"num_disparities": 8, "min_disparity": 1.0},
            TypeError,
            "min_disparity must be an integer, got float",
        ),
        (
            {"num_disparities": 8, "block_size": 4},
            ValueError,
            r"block_size must be an odd integer in \[3, 63\] for cost='census' \(block costs are"
            r" summed in 16 bits\), got 4",
        ),
        (
            {"num_disparities": 8, "block_size": 1},
            ValueError,
            "block_size must be an odd integer in .* got 1",
        ),
        (
            {"num_disparities": 8, "block_size": 65},
            ValueError,
            "block_size must be an odd integer in .* got 65",
        ),
        (
            {"num_disparities": 8, "block_size": 33, "cost": "sad"},
            ValueError,
            r"block_size must be an odd integer in \[3, 31\] for cost='sad'.* got 33",
        ),
        (
            {"num_disparities": 8, "block_size": 9.0},
            TypeError,
            "block_size must be an integer, got float",
        ),
        (
            {"num_disparities": 8, "cost": "ncc"},
            ValueError,
            "cost must be 'census' or 'sad', got 'ncc'",
        ),
        ({"num_disparities": 8, "cost": 1}, TypeError, "cost must be 'census' or 'sad', got int 1"),
        (
            {"num_disparities": 8, "subpixel": "quadratic"},
            ValueError,
            "subpixel must be True, False, 'parabola' or 'equiangular', got 'quadratic'",
        ),
        (
            {"num_disparities": 8, "subpixel": 1},
            TypeError,
            "subpixel must be True, False, 'parabola' or 'equiangular', got int 1",
        ),
        (
            {"num_disparities": 8, "uniqueness_ratio": -1},
            ValueError,
            "uniqueness_ratio must be a finite number >= 0, got -1",
        ),
        (
            {"num_disparities": 8, "uniqueness_ratio": float("nan")},
            ValueError,
            "uniqueness_ratio must be a finite number >= 0, got nan",
        ),
        (
            {"num_disparities": 8, "uniqueness_ratio": "10"},
            TypeError,
            "uniqueness_ratio must be a real number, got str '10'",
        ),
        (
            {"num_disparities": 8, "texture_threshold": -0.5},
            ValueError,
            "texture_threshold must be a finite number >= 0, got -0.5",
        ),
        (
            {"num_disparities": 8, "texture_threshold": float("inf")},
            ValueError,
            "texture_threshold must be a finite number >= 0, got inf",
        ),
        (
            {"num_disparities": 8, "lr_max_diff": -1},
            ValueError,
            "lr_max_diff must be a finite number >= 0, got -1",
        ),
        (
            {"num_disparities": 8, "lr_max_diff": float("nan")},
            ValueError,
            "lr_max_diff must be a finite number >= 0, got nan",
        ),
        (
            {"num_disparities": 8, "lr_max_diff": "1"},
            TypeError,
            "lr_max_diff must be a real number, got str",
        ),
        (
            {"num_disparities": 8, "speckle_window": -1},
            ValueError,
            "speckle_window must be an integer >= 0, got -1",
        ),
        (
            {"num_disparities": 8, "speckle_window": 2.5},
            TypeError,
            "speckle_window must be an integer, got float 2.5",
        ),
        (
            {"num_disparities": 8, "speckle_range": -1.0},
            ValueError,
            "speckle_range must be a finite number >= 0, got -1.0",
        ),
        (
            {"num_disparities": 8, "speckle_range": float("nan")},
            ValueError,
            "speckle_range must be a finite number >= 0, got nan",
        ),
        (
            {"num_disparities": 8, "threads": -1},
            ValueError,
            "threads must be an integer >= 0, got -1",
        ),
        (
            {"num_disparities": 8, "threads": 1.5},
            TypeError,
            "threads must be an integer, got float 1.5",
        ),
        # Beyond a C int pybind11 raised its own TypeError, which names no parameter.
        (
            {"num_disparities": 8, "threads": 2**31},
            ValueError,
            "threads must be an integer <= 2147483647, got 2147483648",
        ),
        (
            {"num_disparities": 8, "speckle_window": 2**40},
            ValueError,
            "speckle_window must be an integer <= 2147483647, got 1099511627776",
        ),
        (
            {"num_disparities": 8, "return_confidence": "yes"},
            TypeError,
            "return_confidence must be a bool, got str 'yes'",
        ),
    ],
)
def test_rejected_parameters(kwargs: dict[str, Any], exc: type[Exception], match: str) -> None:
    with pytest.raises(exc, match=match):
        sd.block_match(*GOOD, **kwargs)
    with pytest.raises(exc, match=match):
        sd.StereoMatcher(**kwargs)
    with pytest.raises(exc, match=match):
        ref.block_match(*GOOD, **kwargs)


L8 = np.zeros((6, 9), np.uint8)


@pytest.mark.parametrize(
    ("left", "right", "exc", "match"),
    [
        (
            [[1, 2], [3, 4]],
            L8,
            TypeError,
            r"left must be a numpy.ndarray \(2-D uint8 or uint16 grey, or \(H, W, 3\) uint8 RGB\),"
            r" got list",
        ),
        (L8, "right.png", TypeError, "right must be a numpy.ndarray .* got str"),
        # block_match's clean-up then took the list's shape and raised numpy's "setting an
        # array element with a sequence ... inhomogeneous shape" instead
        ([[1, 2], [3]], L8, TypeError, r"left must be a numpy.ndarray .* got list$"),
        (
            L8.astype(np.float32),
            L8,
            TypeError,
            r"left must be 2-D uint8 or uint16 grey, or \(H, W, 3\) uint8 RGB, got dtype float32",
        ),
        (L8, L8.astype(np.int16), TypeError, "right must be .* got dtype int16"),
        (
            np.zeros((6, 9, 4), np.uint8),
            L8,
            ValueError,
            r"left must be .* got shape \(6, 9, 4\) uint8",
        ),
        (
            np.zeros((6, 9, 3), np.uint16),
            L8,
            ValueError,
            r"left must be .* got shape \(6, 9, 3\) uint16",
        ),
        (np.zeros(9, np.uint8), L8, ValueError, r"left must be .* got shape \(9,\)"),
        (
            np.zeros((0, 9), np.uint8),
            np.zeros((0, 9), np.uint8),
            ValueError,
            r"left must have at least one row and one column, got shape \(0, 9\)",
        ),
        (
            L8,
            np.zeros((6, 8), np.uint8),
            ValueError,
            r"left and right must have the same shape, got \(6, 9\) and \(6, 8\)",
        ),
        (
            L8,
            L8.astype(np.uint16),
            TypeError,
            "left and right must have the same dtype, got uint8 and uint16",
        ),
        (
            L8,
            np.zeros((6, 9, 3), np.uint8),
            ValueError,
            r"left and right must have the same shape, got \(6, 9\) and \(6, 9, 3\)",
        ),
    ],
)
def test_rejected_images(left: Any, right: Any, exc: type[Exception], match: str) -> None:
    with pytest.raises(exc, match=match):
        sd.block_match(left, right, num_disparities=4)
    with pytest.raises(exc, match=match):
        ref.block_match(left, right, num_disparities=4)


def test_rejected_image_too_wide_for_the_disparities() -> None:
    wide = np.zeros((1, 300_000), np.uint8)
    with pytest.raises(ValueError, match="image width times num_disparities must be below 2"):
        sd.block_match(wide, wide, num_disparities=4096)


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize(
    ("num_disparities", "cols"),
    [
        # cols x num_disparities is below 2**30, cols x 4088 (the baseline kernels' 8 lanes)
        # too, but not cols x 4096 (the AVX2 and AVX-512 kernels' 16): the AVX kernels refused
        # it ("got 262144 x 4081", a product below 2**30) and the baseline ran it (35 s, 2 GB)
        (4081, 2**18),
        (8, 2**26),  # 8 x cols = 2**29; 16 x cols = 2**30
    ],
)
def test_width_limit_is_the_same_on_every_isa(isa: str, num_disparities: int, cols: int) -> None:
    wide = np.zeros((1, cols), np.uint8)  # zero pages: refused before anything is read
    matcher = sd.StereoMatcher(num_disparities=num_disparities, isa=isa)
    rounded = -(-num_disparities // 16) * 16
    message = (
        rf"image width times num_disparities must be below 2\^30 with num_disparities rounded "
        rf"up to a multiple of 16 .*, got {cols} x {num_disparities} \({cols} x {rounded} = "
    )
    with pytest.raises(ValueError, match=message):
        matcher.compute(wide, wide)
    with pytest.raises(ValueError, match=message):
        ref.block_match(wide, wide, num_disparities=num_disparities)
    # The kernels' own guard, which a direct call of the binding meets, has the same rule
    # (the baseline rounded up to its 8 lanes and ran these pairs) and shows the product.
    out = np.empty_like(wide, dtype=np.float32)
    native = (
        rf"image width times num_disparities must be below 2\^30 with num_disparities rounded "
        rf"up to a multiple of 16, got {cols} x {num_disparities} \({cols} x {rounded} = "
        rf"{cols * rounded}\)$"
    )
    with pytest.raises(ValueError, match=native):
        matcher._native.compute(wide, wide, out, None, "rgb")


def test_width_limit_is_checked_before_the_pair_is_copied() -> None:
    # A refused pair of views (here broadcast, one pixel in memory) was made contiguous and a
    # uint16 pair stretched first: 2 GB for a (1, 2**28) pair before the ValueError.
    view = np.broadcast_to(np.zeros((1, 1), np.uint16), (1, 2**28))
    before = _peak_rss_mib()
    with pytest.raises(ValueError, match="image width times num_disparities must be below"):
        sd.block_match(view, view, num_disparities=16)
    assert _peak_rss_mib() - before < 256


def _peak_rss_mib() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def test_matcher_rejects_missing_and_unknown_parameters() -> None:
    missing = "missing 1 required keyword-only argument: 'num_disparities'"
    with pytest.raises(TypeError, match=missing):
        sd.StereoMatcher(block_size=9)
    with pytest.raises(TypeError, match="unexpected keyword argument 'blocksize'"):
        sd.StereoMatcher(num_disparities=8, blocksize=9)


MAX_DOUBLE = float(np.finfo(np.float64).max)


@pytest.mark.parametrize("ratio", [6553399.0, 6553400.0, 1e7, 1e20, 1e300, 1e308, MAX_DOUBLE])
@pytest.mark.parametrize("cost", ["census", "sad"])
def test_huge_uniqueness_ratio_matches_the_oracle(ratio: float, cost: str) -> None:
    # A ratio of 1e20 hung the matcher's constructor: its table loop added 1.0 to a double
    # too large to change. From 6553400 on (a factor of 65535 x 100) no second-best cost
    # passes a winner above 0; a winning cost of 0 still passes. From 1e308 on the oracle's
    # best * factor overflows to inf (it printed numpy's overflow RuntimeWarning).
    rng = np.random.default_rng(11)
    left = rng.integers(0, 256, (24, 40), dtype=np.uint8)
    right = np.roll(left, -3, axis=1)
    right[:8, ::7] = 0  # winners above cost 0 in the top rows, 0 below
    got = sd.block_match(left, right, num_disparities=8, cost=cost, uniqueness_ratio=ratio)
    want = ref.block_match(left, right, num_disparities=8, cost=cost, uniqueness_ratio=ratio)
    np.testing.assert_array_equal(got, want, strict=True)
    assert np.isfinite(got).any() and np.isnan(got).any()


def test_native_layer_rejects_bad_parameters_too() -> None:
    # The C++ core validates on its own (for C++ users): a ValueError naming the rule.
    from stereodepth import _core

    args = [8, 0, 9, "census", "equiangular", 10.0, 0.0, 1.0, 0, 1.0, 1]
    bad = list(args)
    bad[2] = 4
    with pytest.raises(ValueError, match="block_size must be an odd integer in"):
        _core.BlockMatcher(*bad)
    bad = list(args)
    bad[0] = 0
    with pytest.raises(ValueError, match="num_disparities must be an integer in"):
        _core.BlockMatcher(*bad)
    bad = list(args)
    bad[3] = "ncc"
    with pytest.raises(ValueError, match="cost must be 'census' or 'sad'"):
        _core.BlockMatcher(*bad)
    m = _core.BlockMatcher(*args)
    out = np.empty((6, 9), np.float32)
    with pytest.raises(ValueError, match="same shape"):
        m.compute(L8, np.zeros((6, 8), np.uint8), out)
    with pytest.raises(TypeError, match="disparity must have dtype float32"):
        m.compute(L8, L8, np.empty((6, 9), np.float64))
    with pytest.raises(ValueError, match="disparity must have the shape of the images"):
        m.compute(L8, L8, np.empty((6, 8), np.float32))


@pytest.mark.parametrize(
    ("value", "kwargs", "exc", "match"),
    [
        (
            np.zeros((2, 2), np.int16),
            {},
            TypeError,
            "disparity must be a float array .* got dtype int16",
        ),
        (
            np.full((2, 2), 2048.0, np.float32),
            {},
            ValueError,
            r"disparity must be below 2048 px to fit OpenCV's int16 x16 format, got 2048.0",
        ),
        (
            np.array([[3.0, 20.0]], np.float32),
            {"min_disparity": 16},
            ValueError,
            r"disparity must be >= min_disparity \(16\) px or NaN: .* got 3.0 px",
        ),
        (
            np.full((2, 2), -2048.0, np.float32),
            {"min_disparity": -2047},
            ValueError,
            r"disparity must be >= min_disparity \(-2047\) px or NaN",
        ),
        (np.full((2, 2), np.inf, np.float32), {}, ValueError, "disparity must be finite or NaN"),
        (  # the message showed the rounding, "got 2048.0", as if 2047.97 were 2048
            np.full((2, 2), 2047.97, np.float64),
            {},
            ValueError,
            r"below 2048 px to fit .* format, got 2047\.97 \(2048\.0 px in sixteenths\)$",
        ),
        (
            np.array([[-0.04]]),
            {},
            ValueError,
            r"min_disparity \(0\) px or NaN: .* got -0\.04 px \(-0\.0625 px in sixteenths\)$",
        ),
        (
            np.zeros((2, 2), np.float32),
            {"min_disparity": 4000},
            ValueError,
            r"min_disparity must be in \[-2047, 2047\]",
        ),
        (  # its holes fit int16, but no disparity does (from_opencv_disparity refuses it too)
            np.full((2, 2), np.nan, np.float32),
            {"min_disparity": 2048},
            ValueError,
            r"min_disparity must be in \[-2047, 2047\] .* got 2048$",
        ),
        (
            np.zeros((2, 2), np.float32),
            {"min_disparity": 1.5},
            TypeError,
            "min_disparity must be an integer",
        ),
        # numpy's "setting an array element with a sequence", naming nothing
        ([[1.5], [2.0, 3.0]], {}, ValueError, r"disparity must be a rectangular array .* list"),
        # maps of any other shape came out in that shape (from_opencv_disparity refuses them)
        (
            np.float32(3.2),
            {},
            ValueError,
            r"disparity must have shape \(H, W\) or \(N, H, W\), got \(\)$",
        ),
        (np.zeros(3), {}, ValueError, r"disparity must have shape .*, got \(3,\)$"),
        (np.zeros((1, 1, 2, 2)), {}, ValueError, r"got \(1, 1, 2, 2\)$"),
        # numpy's "RuntimeWarning: overflow encountered in multiply" came first (x 16)
        (
            np.array([[1.7e308]]),
            {},
            ValueError,
            r"below 2048 px to fit .* format, got 1\.7e\+308 \(inf px in sixteenths\)$",
        ),
    ],
)
def test_to_opencv_disparity_rejects(
    value: Any, kwargs: dict[str, Any], exc: type[Exception], match: str
) -> None:
    with pytest.raises(exc, match=match):
        sd.to_opencv_disparity(value, **kwargs)


@pytest.mark.parametrize("isa", SUPPORTED_ISAS)
@pytest.mark.parametrize("ratio", [0, 15, 60, 400])
def test_each_isa_near_the_largest_block_costs(isa: str, ratio: float) -> None:
    # A right image that is the left one inverted: nearly every census bit differs, so the
    # block costs of a 15 x 15 block come close to their largest value (15 * 15 * 16), and
    # the uniqueness thresholds of large ratios pass the 16-bit range that the SIMD passes
    # compare in (capped there, as in the scalar pass).
    rng = np.random.default_rng(21)
    left = rng.integers(0, 256, (40, 150), dtype=np.uint8)
    right = np.roll(255 - left, -6, axis=1)
    right[:, 70:] = np.roll(left, -6, axis=1)[:, 70:]  # and a part that matches
    kw = {"num_disparities": 48, "block_size": 15, "uniqueness_ratio": ratio}
    for cfg in ({}, {"return_confidence": True}):
        scalar = sd.StereoMatcher(isa="baseline", **kw, **cfg).compute(left, right)
        simd = sd.StereoMatcher(isa=isa, **kw, **cfg).compute(left, right)
        if isinstance(scalar, tuple):
            for a, b in zip(scalar, simd, strict=True):
                np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_array_equal(scalar, simd)


@pytest.mark.parametrize("kind", ["bm", "sgm"])
def test_a_matchers_parameters_cannot_be_assigned(kind: str) -> None:
    # m.num_disparities = 128 made a new attribute that the matcher never read: it went on
    # searching 64 disparities, silently.
    cls = sd.StereoMatcher if kind == "bm" else sd.SemiGlobalMatcher
    m = cls(num_disparities=64)
    with pytest.raises(AttributeError, match=r"fixed when it is made.*'num_disparities': 128"):
        m.num_disparities = 128  # type: ignore[misc]
    assert m.params["num_disparities"] == 64
    # The recipe the message gives makes the matcher wanted.
    wider = cls(**{**m.params, "num_disparities": 128})
    assert wider.params == {**m.params, "num_disparities": 128}
    assert m.isa == wider.isa == sd.build_info()["isa"]
