"""Pixel formats of the block matcher: uint16 images that do not span 0..65535 (12-bit cameras,
narrow-band thermal cameras, 8-bit values in uint16) and the channel order of colour images
(OpenCV's BGR).

The rules are step 1 of the stereodepth.matching docstring: a uint16 pair is stretched from its
joint [min, max] onto 0..65280 (= 255 * 256) before matching; (H, W, 3) images are R, G, B
unless ``channel_order="bgr"``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth as sd
from stereodepth import _core, cli, matching
from stereodepth import reference as ref
from stereodepth._reference_block_match import grey, stretched
from stereodepth.metrics import evaluate

# ------------------------------------------------------------------------------------------
# Helpers


def random_dots(
    shape: tuple[int, ...], shift: int, *, seed: int, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A random-dot pair drawn from ``values``: left[y, x] = right[y, x - shift]."""
    rng = np.random.default_rng(seed)
    h, w = shape[:2]
    canvas = rng.choice(values, size=(h, w + shift, *shape[2:]))
    left = np.ascontiguousarray(canvas[:, shift:])
    right = np.ascontiguousarray(canvas[:, :w])
    return left, right


def full_range_u8_pair(shape: tuple[int, int], shift: int, *, seed: int) -> tuple[Any, Any]:
    """A uint8 random-dot pair whose joint range is exactly 0..255."""
    left, right = random_dots(shape, shift, seed=seed, values=np.arange(256, dtype=np.uint8))
    left[0, 0], right[-1, -1] = 0, 255
    return left, right


def assert_agree(native: Any, oracle: Any) -> None:
    """The same NaNs, disparities within 1e-3 px (the sub-pixel step), confidence within 1e-6."""
    if isinstance(oracle, tuple):
        assert_agree(native[0], oracle[0])
        np.testing.assert_allclose(native[1], oracle[1], rtol=0, atol=1e-6)
        return
    np.testing.assert_array_equal(np.isnan(native), np.isnan(oracle))
    np.testing.assert_allclose(native, oracle, rtol=0, atol=1e-3)


def assert_identical(a: Any, b: Any) -> None:
    if isinstance(a, tuple):
        assert isinstance(b, tuple) and len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y, strict=True)
    else:
        np.testing.assert_array_equal(a, b, strict=True)


# The uint16 encodings of a uint8 image v met in practice.
ENCODINGS = {
    "v*16": lambda v: v.astype(np.uint16) * 16,  # 12-bit, left-aligned in 0..4080
    "v": lambda v: v.astype(np.uint16),  # 8-bit values stored in uint16
    "12-bit": lambda v: ((v.astype(np.uint32) * 4095 + 127) // 255).astype(np.uint16),
    "7000+6v": lambda v: (7000 + 6 * v.astype(np.uint32)).astype(np.uint16),  # thermal band
}


# ------------------------------------------------------------------------------------------
# The uint16 stretch itself


@pytest.mark.parametrize(
    ("lo", "hi"),
    [
        (0, 1),  # two levels
        (7000, 8530),  # a thermal band
        (0, 4095),  # 12-bit
        (255, 255 + 65279),  # one level less than the scale
        (100, 100 + 65280),  # exactly the scale: a shift
        (0, 65535),  # full range: one level in 256 merges
        (65534, 65535),
    ],
)
def test_stretch_maps_the_joint_range_onto_0_65280(lo: int, hi: int) -> None:
    rng = np.random.default_rng(lo ^ hi)
    left = rng.integers(lo, hi + 1, (9, 31)).astype(np.uint16)
    right = rng.integers(lo, hi + 1, (9, 31)).astype(np.uint16)
    left[0, 0], right[0, 0] = lo, hi  # the joint range, split over the two images
    lc, rc = left.copy(), right.copy()
    sl, sr = matching.stretch_uint16_pair(left, right)
    assert sl.dtype == sr.dtype == np.uint16
    assert sl[0, 0] == 0 and sr[0, 0] == 65280
    # The oracle's formula, written independently (int64 per pixel, no table).
    ol, orr = stretched(left.astype(np.int32), right.astype(np.int32))
    np.testing.assert_array_equal(sl, ol)
    np.testing.assert_array_equal(sr, orr)
    np.testing.assert_array_equal(left, lc)  # the inputs are not modified
    np.testing.assert_array_equal(right, rc)
    # Every value of the range, in order: monotone, strictly so while hi - lo <= 65280.
    every = np.arange(lo, hi + 1, dtype=np.uint16)[None, :]
    table = matching.stretch_uint16_pair(every, every)[0][0].astype(np.int64)
    steps = np.diff(table)
    assert (steps >= 0).all()
    if hi - lo <= 65280:
        assert (steps >= 1).all()
    # Rounded to the nearest level: within half a level of the exact value.
    exact = (np.arange(hi - lo + 1) * 65280) / (hi - lo)
    assert np.abs(table - exact).max() <= 0.5


def test_stretch_keeps_a_constant_pair() -> None:
    left = np.full((4, 5), 4000, np.uint16)
    sl, sr = matching.stretch_uint16_pair(left, left.copy())
    np.testing.assert_array_equal(sl, left)
    np.testing.assert_array_equal(sr, left)
    # ... which matches as any constant pair does: no texture, nothing valid but the ties.
    kw: dict[str, Any] = {"num_disparities": 4, "cost": "sad", "return_confidence": True}
    assert_agree(sd.block_match(left, left, **kw), ref.block_match(left, left, **kw))


# The native stretch (the matchers' own, stereodepth._core._stretch_uint16_pair) against the
# oracle's int64 formula, on every instruction set: every value 0..65535 over many spans.

ISAS: list[str] = list(sd.build_info()["supported_isas"])
EVERY_VALUE = np.arange(65536, dtype=np.uint16).reshape(256, 256)


def span_ranges(n: int, seed: int) -> list[tuple[int, int]]:
    """(lo, hi) for the spans where a float quotient is most likely to be off (the smallest,
    the powers of two and their neighbours, the scale 65280 and the full range) and n random
    ones, each at a random offset."""
    rng = np.random.default_rng(seed)
    spans = {1, 2, 3, 5, 7, 255, 256, 257, 4095, 4096, 65279, 65280, 65281, 65534, 65535}
    spans |= {2**k + e for k in range(1, 16) for e in (-1, 0, 1) if 1 <= 2**k + e <= 65535}
    spans |= {int(v) for v in rng.integers(1, 65536, n)}
    out = []
    for span in sorted(spans):
        lo = int(rng.integers(0, 65536 - span))
        out.append((lo, lo + span))
    return out


@pytest.mark.parametrize("isa", ISAS)
def test_native_stretch_is_the_oracles_for_every_value(isa: str) -> None:
    # Each range clips the values outside it; every value of 0..65535 is stretched by each.
    wrong = []
    for lo, hi in span_ranges(120, seed=ISAS.index(isa)):
        nl, nr = _core._stretch_uint16_pair(EVERY_VALUE, EVERY_VALUE[::-1].copy(), (lo, hi), 0, isa)
        ol, orr = stretched(
            EVERY_VALUE.astype(np.int32), EVERY_VALUE[::-1].astype(np.int32), (lo, hi)
        )
        assert nl.dtype == nr.dtype == np.uint16
        if not (np.array_equal(nl, ol) and np.array_equal(nr, orr)):
            wrong.append((lo, hi))
    assert wrong == []


@pytest.mark.parametrize("isa", ISAS)
@pytest.mark.parametrize("shape", [(1, 1), (1, 37), (37, 1), (130, 67), (257, 301)])
@pytest.mark.parametrize("threads", [1, 2, 3])
def test_native_stretch_of_the_joint_range(isa: str, shape: tuple[int, int], threads: int) -> None:
    # Odd sizes (rows split between threads, row tails past any vector width), the range split
    # between the two images, and the inputs left as they were.
    rng = np.random.default_rng(shape[0] * 1000 + shape[1] + threads)
    lo, hi = sorted(int(v) for v in rng.integers(0, 65536, 2))
    hi = max(hi, lo + 1)
    left = rng.integers(lo, hi + 1, shape).astype(np.uint16)
    right = rng.integers(lo, hi + 1, shape).astype(np.uint16)
    left.flat[-1], right.flat[0] = lo, hi
    if left.size > 1:
        left.flat[0] = hi
    lc, rc = left.copy(), right.copy()
    nl, nr = _core._stretch_uint16_pair(left, right, None, threads, isa)
    ol, orr = matching.stretch_uint16_pair(left, right)
    np.testing.assert_array_equal(nl, ol)
    np.testing.assert_array_equal(nr, orr)
    np.testing.assert_array_equal(left, lc)
    np.testing.assert_array_equal(right, rc)
    assert nl.flags.c_contiguous and nl is not left and nr is not right


def test_native_stretch_keeps_a_constant_pair() -> None:
    left = np.full((4, 5), 4000, np.uint16)
    right = left.copy()
    sl, sr = _core._stretch_uint16_pair(left, right)
    assert sl is left and sr is right
    # With a range the constant pair is stretched (here: clipped to hi, the top of the scale).
    sl, sr = _core._stretch_uint16_pair(left, right, (0, 1000))
    assert (sl == 65280).all() and (sr == 65280).all()


def test_the_matchers_use_the_native_stretch(monkeypatch: pytest.MonkeyPatch) -> None:
    # A 12-bit pair with a fixed range and with its own: the native matchers' stretch (native
    # kernel) and the oracles' (numpy) give the same disparity, with both matchers.
    calls = []
    native_stretch = _core._stretch_uint16_pair

    def counted(*args: Any) -> Any:
        calls.append(args[2:])
        return native_stretch(*args)

    monkeypatch.setattr(_core, "_stretch_uint16_pair", counted)
    rng = np.random.default_rng(3)
    base = rng.integers(0, 4096, (40, 96)).astype(np.uint16)
    left, right = base[:, 4:84].copy(), base[:, :80].copy()
    for kw in ({}, {"intensity_range": (100, 3900)}):
        for native, oracle in (
            (sd.block_match, ref.block_match),
            (sd.semi_global_match, ref.semi_global_match),
        ):
            got = native(left, right, num_disparities=8, **kw)
            want = oracle(left, right, num_disparities=8, **kw)
            np.testing.assert_allclose(got, want, atol=1e-3, equal_nan=True)
            assert np.isnan(got).sum() == np.isnan(want).sum()
    # Once per native call, with the range and the matcher's thread count (0: one per CPU).
    assert calls == [(None, 0), (None, 0), ((100, 3900), 0), ((100, 3900), 0)]


U16 = np.zeros((2, 2), np.uint16)


@pytest.mark.parametrize(
    ("args", "exc", "match"),
    [
        ((np.zeros((2, 2), np.uint8), U16), TypeError, "left must be a 2-D uint16"),
        ((U16, np.zeros((2, 2, 1), np.uint16)), ValueError, "right must be a 2-D"),
        ((np.zeros((0, 2), np.uint16),) * 2, ValueError, "H, W >= 1"),
        ((np.zeros((2, 4), np.uint16)[:, ::2], U16), TypeError, "C-contiguous"),
        (
            (np.ma.masked_array(U16, [[1, 0], [0, 0]]), U16),
            TypeError,
            "left must not be a masked array",
        ),
        ((U16, np.zeros((2, 3), np.uint16)), ValueError, "same shape"),
        # intensity_range: matching.check_intensity_range's rule, bit for bit.
        ((U16, U16, (5, 5)), ValueError, r"intensity_range .* got \(5, 5\)"),
        ((U16, U16, (1, 70000)), ValueError, "intensity_range .* 65535"),
        ((U16, U16, (0, 2**40)), ValueError, "intensity_range"),
        ((U16, U16, (0, 2**70)), ValueError, "intensity_range"),
        ((U16, U16, (1, 2, 3)), TypeError, "intensity_range must be None or two integers"),
        ((U16, U16, (False, True)), TypeError, "intensity_range .* got bool"),
        ((U16, U16, (0.0, 5)), TypeError, "intensity_range .* got float"),
        ((U16, U16, b"\x00\x05"), TypeError, "intensity_range"),
        ((U16, U16, np.array([0, 5])), TypeError, "intensity_range"),
        # threads: an int (not a bool) in [0, 2**31 - 1].
        ((U16, U16, None, -1), ValueError, "threads .* got -1"),
        ((U16, U16, None, 2**31), ValueError, "threads .* got 2147483648"),
        ((U16, U16, None, True), TypeError, "threads .* got bool"),
        ((U16, U16, None, 1.5), TypeError, "threads .* got float"),
        ((U16, U16, None, None), TypeError, "threads .* got NoneType"),
    ],
)
def test_native_stretch_rejects(args: tuple[Any, ...], exc: type[Exception], match: str) -> None:
    with pytest.raises(exc, match=match):
        _core._stretch_uint16_pair(*args)


def test_native_stretch_takes_what_the_public_rules_take() -> None:
    # numpy integers and lists for the range, numpy integers for threads (as the public
    # checks accept them).
    left = np.array([[100, 200], [300, 400]], np.uint16)
    want = matching.stretch_uint16_pair(left, left, (0, 5))
    for ir in ((np.int64(0), np.uint16(5)), [0, 5]):
        got = _core._stretch_uint16_pair(left, left, ir, np.int32(2))
        np.testing.assert_array_equal(got[0], want[0])


# ------------------------------------------------------------------------------------------
# The native matcher against the oracle on narrow uint16 ranges


NARROW_RANGES = {
    "binary": np.array([30000, 30001], np.uint16),
    "12-bit": np.arange(4096, dtype=np.uint16),
    "v*16": (np.arange(256) * 16).astype(np.uint16),
    "thermal": (7000 + 6 * np.arange(256)).astype(np.uint16),
    "top-band": np.arange(65500, 65536, dtype=np.uint16),
    "full": np.arange(65536, dtype=np.uint16),
}
PIXEL_CONFIGS: list[dict[str, Any]] = [
    {"cost": "census", "texture_threshold": 6.0, "return_confidence": True},
    {"cost": "sad", "return_confidence": True},
    {"cost": "sad", "texture_threshold": 4.0, "subpixel": "parabola", "lr_max_diff": None},
]


@pytest.mark.parametrize(
    "cfg", PIXEL_CONFIGS, ids=lambda c: ",".join(f"{k}={v}" for k, v in c.items())
)
@pytest.mark.parametrize("name", list(NARROW_RANGES))
def test_narrow_uint16_ranges_match_the_oracle(name: str, cfg: dict[str, Any]) -> None:
    left, right = random_dots((23, 71), 5, seed=len(name), values=NARROW_RANGES[name])
    kw = {"num_disparities": 11, **cfg}
    assert_agree(sd.block_match(left, right, **kw), ref.block_match(left, right, **kw))


@pytest.mark.parametrize("name", ["v*16", "v", "7000+6v", "v*256", "v*257", "v*128+900"])
@pytest.mark.parametrize("cost", ["census", "sad"])
def test_uint16_encodings_of_a_full_range_uint8_pair_match_it_exactly(name: str, cost: str) -> None:
    # (12-bit, round(v * 4095 / 255), is not affine in v: the scene test covers it.)
    encode = {
        **ENCODINGS,
        "v*256": lambda v: v.astype(np.uint16) * 256,
        "v*257": lambda v: v.astype(np.uint16) * 257,
        "v*128+900": lambda v: (v.astype(np.uint32) * 128 + 900).astype(np.uint16),
    }[name]
    left, right = full_range_u8_pair((24, 70), 6, seed=11)
    kw: dict[str, Any] = {
        "num_disparities": 12,
        "cost": cost,
        "texture_threshold": 5.0,
        "return_confidence": True,
    }
    want = sd.block_match(left, right, **kw)
    assert_identical(sd.block_match(encode(left), encode(right), **kw), want)
    assert_agree(ref.block_match(encode(left), encode(right), **kw), want)


def test_texture_threshold_is_in_grey_levels_of_the_stretch() -> None:
    # 12-bit data (v * 16): before the stretch its Sobel response (>> 8) all but vanished and
    # nearly every block failed the texture check; now the check sees uint8 grey levels.
    left, right = full_range_u8_pair((20, 60), 4, seed=12)
    kw: dict[str, Any] = {
        "num_disparities": 8,
        "uniqueness_ratio": 0,
        "lr_max_diff": None,
        "speckle_window": 0,
    }
    inside = np.isfinite(sd.block_match(left, right, **kw)).mean()  # the search range only
    u8 = sd.block_match(left, right, texture_threshold=28.0, **kw)
    assert 0.5 * inside < np.isfinite(u8).mean() < inside  # the check keeps some, drops some
    u12 = left.astype(np.uint16) * 16, right.astype(np.uint16) * 16
    np.testing.assert_array_equal(sd.block_match(*u12, texture_threshold=28.0, **kw), u8)


@pytest.mark.parametrize("cost", ["census", "sad"])
def test_a_fixed_intensity_range_matches_the_oracle_and_clips(cost: str) -> None:
    # 12-bit data with a few values outside the stated band (hot and cold pixels).
    left, right = random_dots((21, 66), 4, seed=13, values=np.arange(800, 3300, dtype=np.uint16))
    left[3, 10], right[7, 40], left[15, 50] = 0, 65535, 4095
    kw: dict[str, Any] = {
        "num_disparities": 10,
        "cost": cost,
        "texture_threshold": 3.0,
        "return_confidence": True,
        "intensity_range": (1000, 3000),
    }
    got = sd.block_match(left, right, **kw)
    assert_agree(got, ref.block_match(left, right, **kw))
    # Values outside the range count as its ends.
    clipped = np.clip(left, 1000, 3000), np.clip(right, 1000, 3000)
    assert_identical(sd.block_match(*clipped, **kw), got)
    # The pair's own range, stated, is the default.
    kw["intensity_range"] = (int(min(left.min(), right.min())), int(max(left.max(), right.max())))
    auto = {k: v for k, v in kw.items() if k != "intensity_range"}
    assert_identical(sd.block_match(left, right, **kw), sd.block_match(left, right, **auto))
    m = sd.StereoMatcher(**kw)
    assert m.params["intensity_range"] == kw["intensity_range"]
    assert_identical(m.compute(left, right), sd.block_match(left, right, **auto))


def test_a_fixed_intensity_range_gives_frames_one_scale() -> None:
    # Two frames of a 12-bit stream, the second with a hot pixel: stretched over their own
    # ranges they are matched at different scales; over the sensor's range at one.
    left, right = random_dots((30, 80), 4, seed=14, values=np.arange(1000, 1400, dtype=np.uint16))
    hot_l, hot_r = left.copy(), right.copy()
    hot_l[0, -1] = hot_r[0, -1] = 4095
    kw: dict[str, Any] = {"num_disparities": 8, "cost": "sad", "speckle_window": 0}
    fixed = {**kw, "intensity_range": (0, 4095)}
    a, b = sd.block_match(left, right, **fixed), sd.block_match(hot_l, hot_r, **fixed)
    far = np.s_[5:, :-10]  # away from the hot pixel
    np.testing.assert_array_equal(a[far], b[far])
    own_a, own_b = sd.block_match(left, right, **kw), sd.block_match(hot_l, hot_r, **kw)
    assert not np.array_equal(own_a[far], own_b[far], equal_nan=True)


# ------------------------------------------------------------------------------------------
# The shared scenes: every uint16 encoding as good as the uint8 min-max stretch


def min_max_stretch_u8(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pair stretched from its joint [min, max] to 0..255 (float, rounded)."""
    lo = float(min(left.min(), right.min()))
    hi = float(max(left.max(), right.max()))

    def one(a: np.ndarray) -> np.ndarray:
        return np.rint((a.astype(np.float64) - lo) * 255.0 / (hi - lo)).astype(np.uint8)

    return one(left), one(right)


@pytest.mark.data
@pytest.mark.parametrize("cost", ["census", "sad"])
def test_scenes_as_uint16_score_as_their_uint8_stretch(stereo_scenes: list[Any], cost: str) -> None:
    pytest.importorskip("PIL.Image", reason="reading the scenes needs Pillow (the batch extra)")
    from stereodepth.io import read_image

    names = {s.name for s in stereo_scenes}
    assert {"mb2003-cones", "mb2003-teddy", "mb2001-tsukuba"} <= names
    failures = []
    for scene in stereo_scenes:
        left, right = read_image(scene.left_path), read_image(scene.right_path)
        if left.ndim == 3:
            left, right = grey(left).astype(np.uint8), grey(right).astype(np.uint8)
        gt, mask = scene.gt(), scene.mask()
        nd = 16 * -(-(int(np.ceil(scene.meta["max_disp"])) + 1) // 16)
        for name, encode in ENCODINGS.items():
            el, er = encode(left), encode(right)
            sl, sr = min_max_stretch_u8(el, er)
            scores = {}
            for label, (a, b) in (("uint16", (el, er)), ("uint8", (sl, sr))):
                d = sd.block_match(a, b, num_disparities=nd, cost=cost)
                dt = sd.block_match(a, b, num_disparities=nd, cost=cost, texture_threshold=5)
                scores[label] = (
                    100 * evaluate(d, gt, mask).bad_2,
                    100 * evaluate(dt, gt, mask).density,
                )
            (b16, t16), (b8, t8) = scores["uint16"], scores["uint8"]
            if b16 > b8 + 1.0 or abs(t16 - t8) > 5.0:
                failures.append(
                    f"{scene.name} {cost} {name}: bad-2 {b16:.2f} vs {b8:.2f}, "
                    f"texture density {t16:.2f} vs {t8:.2f}"
                )
    assert not failures, "\n".join(failures)


# ------------------------------------------------------------------------------------------
# Channel order


def colour_pair(seed: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """An RGB random-dot pair, shift 5."""
    return random_dots((26, 64, 3), 5, seed=seed, values=np.arange(256, dtype=np.uint8))


@pytest.mark.parametrize("cost", ["census", "sad"])
def test_bgr_is_matched_as_the_same_image_in_rgb(cost: str) -> None:
    left, right = colour_pair()
    bgr_l, bgr_r = left[..., ::-1], right[..., ::-1]  # views: not contiguous
    kw: dict[str, Any] = {"num_disparities": 10, "cost": cost, "return_confidence": True}
    want = sd.block_match(left, right, **kw)
    got = sd.block_match(bgr_l, bgr_r, channel_order="bgr", **kw)
    assert_identical(got, want)
    assert_agree(ref.block_match(bgr_l, bgr_r, channel_order="bgr", **kw), got)
    matcher = sd.StereoMatcher(channel_order="bgr", **kw)
    assert matcher.params["channel_order"] == "bgr"
    assert "channel_order='bgr'" in repr(matcher)
    assert_identical(matcher.compute(bgr_l, bgr_r), want)
    # Reading BGR as RGB swaps the weights of red and blue: a different grey image.
    assert not np.array_equal(grey(bgr_l), grey(left))
    np.testing.assert_array_equal(grey(bgr_l, channel_order="bgr"), grey(left))


def test_bgr_grey_is_opencvs() -> None:
    cv2 = pytest.importorskip("cv2", reason="OpenCV is not installed")
    bgr = np.random.default_rng(21).integers(0, 256, (17, 23, 3)).astype(np.uint8)
    np.testing.assert_array_equal(
        grey(bgr, channel_order="bgr"), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    )


def test_grey_images_ignore_the_channel_order() -> None:
    left, right = full_range_u8_pair((20, 50), 3, seed=22)
    for pair in ((left, right), (left.astype(np.uint16) * 16, right.astype(np.uint16) * 16)):
        assert_identical(
            sd.block_match(*pair, num_disparities=8, channel_order="bgr"),
            sd.block_match(*pair, num_disparities=8),
        )


def test_cv2_imread_output_matches_as_its_grey_image(tmp_path: Path) -> None:
    cv2 = pytest.importorskip("cv2", reason="OpenCV is not installed")
    left, right = colour_pair(23)
    # Real PNG files, written and read back by OpenCV: cv2.imread returns B, G, R.
    for name, rgb in (("left.png", left), ("right.png", right)):
        assert cv2.imwrite(str(tmp_path / name), np.ascontiguousarray(rgb[..., ::-1]))
    bgr_l = cv2.imread(str(tmp_path / "left.png"))
    bgr_r = cv2.imread(str(tmp_path / "right.png"))
    assert bgr_l.shape == left.shape
    np.testing.assert_array_equal(bgr_l, left[..., ::-1])
    grey_l = cv2.cvtColor(bgr_l, cv2.COLOR_BGR2GRAY)
    grey_r = cv2.cvtColor(bgr_r, cv2.COLOR_BGR2GRAY)
    for cost in ("census", "sad"):
        kw: dict[str, Any] = {"num_disparities": 10, "cost": cost, "return_confidence": True}
        want = sd.block_match(grey_l, grey_r, **kw)
        assert_identical(sd.block_match(bgr_l, bgr_r, channel_order="bgr", **kw), want)
        assert_identical(sd.StereoMatcher(channel_order="bgr", **kw).compute(bgr_l, bgr_r), want)


@pytest.mark.data
def test_cv2_imread_of_a_shared_scene_matches_as_its_grey_image(
    stereo_scenes: list[Any],
) -> None:
    cv2 = pytest.importorskip("cv2", reason="OpenCV is not installed")
    scene = next(s for s in stereo_scenes if s.name == "mb2003-teddy")
    bgr_l, bgr_r = cv2.imread(str(scene.left_path)), cv2.imread(str(scene.right_path))
    assert bgr_l.ndim == 3
    kw: dict[str, Any] = {"num_disparities": 64}
    want = sd.block_match(
        cv2.cvtColor(bgr_l, cv2.COLOR_BGR2GRAY), cv2.cvtColor(bgr_r, cv2.COLOR_BGR2GRAY), **kw
    )
    got = sd.block_match(bgr_l, bgr_r, channel_order="bgr", **kw)
    assert_identical(got, want)
    # Read as RGB (the default), BGR is another grey image and another disparity.
    assert not np.array_equal(sd.block_match(bgr_l, bgr_r, **kw), want, equal_nan=True)
    # ... and as the same files read as RGB (Pillow): the order is the only difference.
    pytest.importorskip("PIL.Image", reason="reading the scenes needs Pillow (the batch extra)")
    from stereodepth.io import read_image

    rgb = sd.block_match(read_image(scene.left_path), read_image(scene.right_path), **kw)
    assert_identical(got, rgb)


# ------------------------------------------------------------------------------------------
# Rejected channel orders, everywhere the option is taken


BAD_ORDERS: list[tuple[Any, type[Exception], str]] = [
    ("RGB", ValueError, r"channel_order must be 'rgb' or 'bgr', got 'RGB'"),
    ("rgba", ValueError, r"channel_order must be 'rgb' or 'bgr', got 'rgba'"),
    (None, TypeError, r"channel_order must be 'rgb' or 'bgr', got NoneType None"),
    (1, TypeError, r"channel_order must be 'rgb' or 'bgr', got int 1"),
]


@pytest.mark.parametrize(("value", "exc", "match"), BAD_ORDERS)
def test_rejected_channel_orders(value: Any, exc: type[Exception], match: str) -> None:
    left, right = colour_pair()
    with pytest.raises(exc, match=match):
        sd.block_match(left, right, num_disparities=4, channel_order=value)
    with pytest.raises(exc, match=match):
        sd.StereoMatcher(num_disparities=4, channel_order=value)
    with pytest.raises(exc, match=match):
        ref.block_match(left, right, num_disparities=4, channel_order=value)
    with pytest.raises(exc, match=match):
        matching.as_pair(left, right, channel_order=value)
    with pytest.raises(exc, match=match):
        grey(left, channel_order=value)


BAD_RANGES: list[tuple[Any, type[Exception], str]] = [
    (
        4095,
        TypeError,
        r"intensity_range must be None or two integers \(lo, hi\) with 0 <= lo "
        r"< hi <= 65535, got int 4095",
    ),
    ((0, 4095, 1), TypeError, r"got tuple \(0, 4095, 1\)"),
    ((0.0, 4095), TypeError, r"got \(0.0, 4095\) \(a float\)"),
    ((True, 4095), TypeError, r"got \(True, 4095\) \(a bool\)"),
    ((5, 5), ValueError, r"0 <= lo < hi <= 65535, got \(5, 5\)"),
    ((-1, 10), ValueError, r"got \(-1, 10\)"),
    ((0, 65536), ValueError, r"got \(0, 65536\)"),
]


@pytest.mark.parametrize(("value", "exc", "match"), BAD_RANGES)
def test_rejected_intensity_ranges(value: Any, exc: type[Exception], match: str) -> None:
    left, right = full_range_u8_pair((8, 20), 2, seed=60)
    left16, right16 = left.astype(np.uint16), right.astype(np.uint16)
    with pytest.raises(exc, match=match):
        sd.block_match(left16, right16, num_disparities=4, intensity_range=value)
    with pytest.raises(exc, match=match):
        sd.StereoMatcher(num_disparities=4, intensity_range=value)
    with pytest.raises(exc, match=match):
        ref.block_match(left16, right16, num_disparities=4, intensity_range=value)
    with pytest.raises(exc, match=match):
        matching.as_pair(left16, right16, intensity_range=value)


def test_intensity_range_is_refused_for_uint8_images() -> None:
    left, right = full_range_u8_pair((8, 20), 2, seed=61)
    message = (
        r"intensity_range applies to uint16 images \(uint8 images are matched as they are\), "
        r"got \(0, 255\) with uint8 images"
    )
    with pytest.raises(ValueError, match=message):
        sd.block_match(left, right, num_disparities=4, intensity_range=(0, 255))
    with pytest.raises(ValueError, match=message):
        ref.block_match(left, right, num_disparities=4, intensity_range=(0, 255))


# ------------------------------------------------------------------------------------------
# stereodepth.dask and stereodepth eval


def test_dask_block_match_takes_the_channel_order_and_stretches_per_frame() -> None:
    da = pytest.importorskip("dask.array")
    import stereodepth.dask as sdd

    frames = [colour_pair(30 + i) for i in range(3)]
    left = np.stack([f[0][..., ::-1] for f in frames])  # BGR stacks
    right = np.stack([f[1][..., ::-1] for f in frames])
    lazy = sdd.block_match(
        da.from_array(left, chunks=(1, 13, 64, 3)),
        da.from_array(right, chunks=(1, 13, 64, 3)),
        num_disparities=10,
        channel_order="bgr",
    )
    got = lazy.compute(scheduler="synchronous")
    for i, (rgb_l, rgb_r) in enumerate(frames):
        np.testing.assert_array_equal(got[i], sd.block_match(rgb_l, rgb_r, num_disparities=10))
    # uint16 frames of different ranges: each is stretched over its own range.
    u8 = [full_range_u8_pair((20, 48), 3, seed=40 + i) for i in range(2)]
    ul = np.stack([u8[0][0].astype(np.uint16) * 16, u8[1][0].astype(np.uint16) + 7000])
    ur = np.stack([u8[0][1].astype(np.uint16) * 16, u8[1][1].astype(np.uint16) + 7000])
    got16 = sdd.block_match(
        da.from_array(ul), da.from_array(ur), num_disparities=8, cost="sad"
    ).compute(scheduler="synchronous")
    for i, (a, b) in enumerate(u8):
        np.testing.assert_array_equal(got16[i], sd.block_match(a, b, num_disparities=8, cost="sad"))
    # One scale for the whole stack: each frame as the numpy function with the same range.
    fixed = sdd.block_match(
        da.from_array(ul), da.from_array(ur), num_disparities=8, intensity_range=(0, 7255)
    ).compute(scheduler="synchronous")
    for i in range(2):
        np.testing.assert_array_equal(
            fixed[i], sd.block_match(ul[i], ur[i], num_disparities=8, intensity_range=(0, 7255))
        )
    with pytest.raises(ValueError, match="intensity_range applies to uint16 images"):
        sdd.block_match(
            da.from_array(left), da.from_array(right), num_disparities=8, intensity_range=(0, 9)
        )
    with pytest.raises(ValueError, match="channel_order must be 'rgb' or 'bgr', got 'brg'"):
        sdd.block_match(
            da.from_array(left), da.from_array(right), num_disparities=8, channel_order="brg"
        )


def write_scene(folder: Path, left: np.ndarray, right: np.ndarray, shift: int) -> None:
    image = pytest.importorskip("PIL.Image", reason="eval reads PNG files with Pillow")
    folder.mkdir(parents=True)
    image.fromarray(left).save(folder / "left.png")
    image.fromarray(right).save(folder / "right.png")
    gt = np.full(left.shape[:2], float(shift), np.float32)
    gt[:, :shift] = np.nan
    np.save(folder / "disp_gt.npy", gt)
    (folder / "meta.json").write_text(json.dumps({"max_disp": shift + 4}))


def eval_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    status = cli.main(["eval", *argv, "--json", "--repeat", "1", "--threads", "1"])
    out, err = capsys.readouterr()
    assert status == 0, err
    report: dict[str, Any] = json.loads(out)
    return report


def test_eval_channel_order(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    left, right = colour_pair(50)
    write_scene(tmp_path / "rgb" / "s", left, right, 5)
    # The same pair with its channels stored B, G, R (an OpenCV array saved through Pillow).
    write_scene(tmp_path / "bgr" / "s", left[..., ::-1].copy(), right[..., ::-1].copy(), 5)
    methods = ["--method", "stereodepth"]
    try:
        import cv2  # noqa: F401
    except ImportError:
        pass
    else:
        methods += ["opencv-bm", "opencv-sgbm"]
    want = eval_json(capsys, str(tmp_path / "rgb"), *methods)
    got = eval_json(capsys, str(tmp_path / "bgr"), *methods, "--channel-order", "bgr")
    assert want["channel_order"] == "rgb" and got["channel_order"] == "bgr"
    assert len(got["results"]) == len(methods) - 1
    for g, w in zip(got["results"], want["results"], strict=True):
        assert (g["method"], g["metrics"]) == (w["method"], w["metrics"])
    # Read as RGB, the swapped files give another grey image (and another score).
    swapped = eval_json(capsys, str(tmp_path / "bgr"), "--method", "stereodepth")
    assert swapped["results"][0]["metrics"] != want["results"][0]["metrics"]


def test_eval_rejects_channel_orders(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    left, right = colour_pair(51)
    write_scene(tmp_path / "s", left, right, 5)
    with pytest.raises(SystemExit) as info:
        cli.main(["eval", str(tmp_path), "--channel-order", "grb"])
    assert info.value.code == 2
    assert "argument --channel-order: invalid choice: 'grb'" in capsys.readouterr().err
    assert cli.main(["eval", str(tmp_path), "--option", "channel_order=bgr"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err == "stereodepth eval: error: --option channel_order: use --channel-order\n"


def test_big_endian_uint16_is_uint16_everywhere() -> None:
    """A big-endian uint16 image (FITS, PGM, ``np.frombuffer(..., ">u2")``) is matched,
    remapped and rectified as the same values in the machine's byte order; it was refused with
    "must be ... uint16 ..., got dtype >u2"."""
    left, right = random_dots((40, 64), 5, seed=3, values=np.arange(0, 4096, 3, dtype=np.uint16))
    big = [a.astype(">u2") for a in (left, right)]
    assert not big[0].dtype.isnative and np.array_equal(big[0], left)
    for match in (sd.block_match, sd.semi_global_match):
        assert_identical(match(*big, num_disparities=16), match(left, right, num_disparities=16))
    for cls in (sd.StereoMatcher, sd.SemiGlobalMatcher):
        m = cls(num_disparities=16)
        assert_identical(m.compute(*big), m.compute(left, right))
    mx, my = np.meshgrid(np.arange(64, dtype=np.float32) * 0.9, np.arange(40, dtype=np.float32))
    want = sd.remap(left, mx, my)
    assert_identical(sd.remap(big[0], mx.astype(">f4"), my.astype(">f4")), want)
    assert_identical(ref.remap(big[0], mx, my), want)
    k = np.array([[60.0, 0, 31.5], [0, 60.0, 19.5], [0, 0, 1]])
    rect = sd.StereoRectifier(
        K1=k, D1=None, K2=k, D2=None, R=np.eye(3), T=[-0.1, 0, 0], image_size=(64, 40)
    )
    for got, expected in zip(rect.rectify(*big), rect.rectify(left, right), strict=True):
        assert_identical(got, expected)
    da = pytest.importorskip("dask.array")
    import stereodepth.dask as sdd

    stack = [da.from_array(np.stack([a, a])) for a in big]
    got = sdd.semi_global_match(*stack, num_disparities=16).compute()
    assert_identical(got[1], sd.semi_global_match(left, right, num_disparities=16))


def test_big_endian_disparity_maps_are_maps_everywhere(tmp_path: Path) -> None:
    """The maps' side of the rule above: a big-endian float32, int16 (OpenCV x16) or uint16
    (KITTI x256) disparity is converted, scored and written as the same values; it was refused
    as "disparity must have dtype float16, float32, ... got >f4" (a float32 map all the same)."""
    rng = np.random.default_rng(4)
    d = (rng.random((6, 7)) * 40 + 1).astype(np.float32)
    d[0, 0] = np.nan
    raw = sd.to_opencv_disparity(d)
    kitti = np.where(np.isnan(d), 0, np.rint(d * 256)).astype(np.uint16)
    rig = {"focal_px": 700.0, "baseline_m": 0.1}
    for a, kw in ((d, {}), (raw, {}), (kitti, {"scale": 1 / 256})):
        big = a.astype(a.dtype.newbyteorder(">"))
        assert not big.dtype.isnative
        assert_identical(
            sd.disparity_to_depth(big, **rig, **kw), sd.disparity_to_depth(a, **rig, **kw)
        )
        assert_identical(sd.reproject(big, **rig, **kw), sd.reproject(a, **rig, **kw))
        assert_identical(
            ref.disparity_to_depth(big, **rig, **kw), ref.disparity_to_depth(a, **rig, **kw)
        )
    assert_identical(sd.from_opencv_disparity(raw.astype(">i2")), sd.from_opencv_disparity(raw))
    gt = d + 0.75
    want = evaluate(d, gt)
    assert evaluate(d.astype(">f4"), gt.astype(">f8")) == want
    assert evaluate(raw.astype(">i2"), gt, min_disparity=0) == evaluate(raw, gt, min_disparity=0)
    sd.io.write_disparity_png16(tmp_path / "be.png", d.astype(">f4"))
    sd.io.write_disparity_png16(tmp_path / "le.png", d)
    assert (tmp_path / "be.png").read_bytes() == (tmp_path / "le.png").read_bytes()
    sd.io.write_png16(tmp_path / "mm.png", kitti.astype(">u2"))
    np.testing.assert_array_equal(sd.io.read_image(tmp_path / "mm.png"), kitti, strict=True)
