"""Each SIMD instruction set against the scalar baseline, bit for bit, on the widest mix of
options the matchers and the conversion kernels take.

The other ISA tests compare uint8 grey pairs with one thread count, or compare with the numpy
oracle (which allows 1e-3 px after the sub-pixel step). These cases put uint16 (with and without
``intensity_range``) and RGB/BGR pairs, both borders, the speckle filter, fill, the extreme
penalties and disparity ranges far from multiples of 16 (negative, positive, wider than 256)
through the SIMD kernels, with another thread count than the baseline's, and ask for the same
bits (NaN in the same places) in the disparity and the confidence. The cases come from a
differential fuzz of the public API on the first AVX-512 machine (no difference found).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import stereodepth as sd
from stereodepth import _core
from stereodepth.depth import DepthOptions
from stereodepth.pointcloud import ReprojectOptions

SUPPORTED_ISAS: list[str] = list(sd.build_info()["supported_isas"])
SIMD_ISAS = [isa for isa in SUPPORTED_ISAS if isa != "baseline"]


def mixed_pair(
    shape: tuple[int, int], shift: int, *, seed: int, kind: str = "grey"
) -> tuple[np.ndarray, np.ndarray]:
    """A random-dot pair (left[y, x] = right[y, x - shift]) with a flat patch (ties), a
    periodic one (work for the uniqueness check) and noise on a part of the right image.
    ``kind``: "grey" (uint8), "grey16" (uint16) or "rgb" (uint8, (H, W, 3))."""
    rng = np.random.default_rng(seed)
    h, w = shape
    top = 65536 if kind == "grey16" else 256
    dtype = np.uint16 if kind == "grey16" else np.uint8
    ch = (3,) if kind == "rgb" else ()
    extra = abs(shift) + 1
    canvas = rng.integers(0, top, (h, w + extra, *ch)).astype(dtype)
    canvas[h // 4 : h // 2 + 1, w // 5 : w // 2 + 1] = top // 2
    period = np.resize(np.array([0, 0, top - 1, top - 1], dtype), w // 3 + 1)
    rows = slice(h // 2, 3 * h // 4 + 1)
    if ch:
        canvas[rows, w // 2 : w // 2 + period.size] = period[None, :, None]
    else:
        canvas[rows, w // 2 : w // 2 + period.size] = period[None, :]
    m = max(0, -shift)
    left = canvas[:, m : m + w].copy()
    right = canvas[:, m + shift : m + shift + w].copy()
    noisy = rng.random((h, w)) < 0.1
    right[noisy] = rng.integers(0, top, (int(noisy.sum()), *ch)).astype(dtype)
    return left, right


def assert_same_bits(scalar: Any, simd: Any) -> None:
    scalar = scalar if isinstance(scalar, tuple) else (scalar,)
    simd = simd if isinstance(simd, tuple) else (simd,)
    assert len(scalar) == len(simd)
    for a, b in zip(scalar, simd, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        finite = ~np.isnan(a)
        np.testing.assert_array_equal(a[finite].view(np.uint32), b[finite].view(np.uint32))


# (shape, kind, shift, options): every option of StereoMatcher at least once, odd ranges.
BLOCK_MATCH_CASES: list[tuple[tuple[int, int], str, int, dict[str, Any]]] = [
    ((23, 131), "grey16", 9, {
        "num_disparities": 37, "min_disparity": -5, "block_size": 7, "subpixel": "parabola",
        "uniqueness_ratio": 10, "lr_max_diff": 0, "speckle_window": 20, "speckle_range": 0.5,
        "texture_threshold": 2.0, "return_confidence": True}),
    ((17, 160), "rgb", 40, {
        "num_disparities": 100, "min_disparity": 3, "block_size": 5, "cost": "sad",
        "subpixel": "equiangular", "uniqueness_ratio": 0.01, "lr_max_diff": None,
        "border": "opencv", "channel_order": "bgr", "return_confidence": True}),
    ((9, 400), "grey", -30, {
        "num_disparities": 270, "min_disparity": -40, "block_size": 11, "subpixel": False,
        "uniqueness_ratio": 0, "lr_max_diff": 1.5, "speckle_window": 0}),
    ((11, 90), "grey16", -4, {
        "num_disparities": 19, "min_disparity": -17, "block_size": 3, "cost": "sad",
        "intensity_range": (1000, 60000), "texture_threshold": 1.0, "speckle_range": 3.7,
        "return_confidence": True}),
    ((13, 77), "grey", -20, {
        "num_disparities": 49, "min_disparity": -60, "block_size": 63, "subpixel": "parabola",
        "uniqueness_ratio": 30, "lr_max_diff": 100, "border": "opencv",
        "return_confidence": True}),
    ((30, 1), "rgb", 0, {"num_disparities": 3, "min_disparity": -1, "return_confidence": True}),
    # 9 rows x 11000 columns x 256 costs: above the 24 MiB budget of the census cost ring, so
    # the SIMD first pass matches the leaving row again instead of reading it back.
    ((12, 11000), "grey", 37, {"num_disparities": 256, "return_confidence": True}),
    ((2, 5), "grey16", 1, {"num_disparities": 1, "min_disparity": 1, "cost": "sad",
                           "return_confidence": True}),
]  # fmt: skip


def sgm_limit(paths: int, block_size: int) -> int:
    return min(65535 // paths, 16383) - 16 * block_size**2


# Every option of SemiGlobalMatcher at least once; each path count; ndisp rounded up to a
# multiple of 32 (the AVX-512 kernels' lanes) and to an odd multiple of 16.
SEMI_GLOBAL_CASES: list[tuple[tuple[int, int], str, int, dict[str, Any]]] = [
    ((70, 131), "grey16", 20, {
        "num_disparities": 64, "min_disparity": -8, "block_size": 1, "p1": 3, "p2": 30,
        "p2_step": 1, "paths": 3, "subpixel": "parabola", "uniqueness_ratio": 5,
        "lr_max_diff": 0, "median": False, "speckle_window": 20, "speckle_range": 0.5,
        "fill": True, "return_confidence": True}),
    ((21, 110), "rgb", 12, {
        "num_disparities": 45, "min_disparity": 5, "p1": 0, "p2": sgm_limit(8, 3),
        "paths": 8, "lr_max_diff": None, "border": "opencv", "channel_order": "bgr",
        "return_confidence": True}),
    ((25, 150), "grey", -35, {
        "num_disparities": 96, "min_disparity": -50, "p2_step": 0, "paths": 4,
        "uniqueness_ratio": 15, "lr_max_diff": 1.5, "fill": True, "return_confidence": True}),
    ((10, 350), "grey", -100, {
        "num_disparities": 300, "min_disparity": -150, "paths": 3, "p1": sgm_limit(3, 3),
        "p2": sgm_limit(3, 3), "speckle_window": 0, "return_confidence": True}),
    ((19, 60), "grey16", 4, {
        "num_disparities": 33, "min_disparity": 0, "block_size": 1, "paths": 8,
        "intensity_range": (0, 4095), "p2_step": 65535, "subpixel": False, "median": True,
        "return_confidence": True}),
    ((9, 1), "grey", 0, {"num_disparities": 16, "min_disparity": -8, "paths": 3,
                         "return_confidence": True}),
    ((1, 7), "rgb", 1, {"num_disparities": 2, "min_disparity": -1, "paths": 4,
                        "fill": True, "return_confidence": True}),
]  # fmt: skip


# (matcher class, index of the case in its list): both matchers' cases.
MATCHER_CASES = [(sd.StereoMatcher, i) for i in range(len(BLOCK_MATCH_CASES))] + [
    (sd.SemiGlobalMatcher, i) for i in range(len(SEMI_GLOBAL_CASES))
]


@pytest.mark.parametrize("isa", SIMD_ISAS)
@pytest.mark.parametrize(
    ("matcher", "case"), MATCHER_CASES, ids=[f"{m.__name__}-{i}" for m, i in MATCHER_CASES]
)
def test_options_mix_matches_baseline(isa: str, matcher: Any, case: int) -> None:
    cases = BLOCK_MATCH_CASES if matcher is sd.StereoMatcher else SEMI_GLOBAL_CASES
    shape, kind, shift, kw = cases[case]
    seed = (100 if matcher is sd.StereoMatcher else 200) + case
    left, right = mixed_pair(shape, shift, seed=seed, kind=kind)
    scalar = matcher(isa="baseline", threads=1, **kw).compute(left, right)
    simd = matcher(isa=isa, threads=3, **kw).compute(left, right)
    assert_same_bits(scalar, simd)
    if shape[0] * shape[1] > 100:  # not a vacuous comparison
        d = scalar[0] if isinstance(scalar, tuple) else scalar
        assert np.isfinite(d).any()


@pytest.mark.parametrize("isa", SIMD_ISAS)
def test_a_reused_matcher_matches_a_fresh_baseline_one(isa: str) -> None:
    # One matcher per class over frames of other sizes and formats (its buffers reused).
    frames = [((40, 97), "grey", 7), ((5, 300), "rgb", 30), ((33, 3), "grey16", 1),
              ((64, 160), "grey", 12)]  # fmt: skip
    bm_kw: dict[str, Any] = {"num_disparities": 41, "min_disparity": -3, "return_confidence": True}
    sgm_kw: dict[str, Any] = {"num_disparities": 48, "min_disparity": -3, "return_confidence": True}
    bm = sd.StereoMatcher(isa=isa, threads=2, **bm_kw)
    sgm = sd.SemiGlobalMatcher(isa=isa, threads=2, **sgm_kw)
    for i, (shape, kind, shift) in enumerate(frames):
        left, right = mixed_pair(shape, shift, seed=300 + i, kind=kind)
        assert_same_bits(
            sd.StereoMatcher(isa="baseline", threads=1, **bm_kw).compute(left, right),
            bm.compute(left, right),
        )
        assert_same_bits(
            sd.SemiGlobalMatcher(isa="baseline", threads=1, **sgm_kw).compute(left, right),
            sgm.compute(left, right),
        )


def disparity_with_specials(dtype: type, shape: tuple[int, ...], seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if dtype == np.int16:
        d = rng.integers(-600, 16 * 300, size=shape).astype(dtype)
        specials = np.array([0, -1, -16, -17, 32767, -32768], dtype)
    elif dtype == np.uint16:
        d = rng.integers(0, 65536, size=shape).astype(dtype)
        specials = np.array([0, 1, 65535], dtype)
    else:
        d = (rng.random(shape) * 300 - 20).astype(dtype)
        f = np.finfo(dtype)
        specials = np.array(
            [0.0, -0.0, np.nan, np.inf, -np.inf, f.max, -f.max, f.tiny, f.smallest_subnormal],
            dtype,
        )
    flat = d.reshape(-1)
    idx = rng.choice(flat.size, size=4 * specials.size, replace=False)
    flat[idx] = np.resize(specials, idx.size)
    return d


DEPTH_OPTIONS: list[dict[str, Any]] = [
    {"doffs_px": 131.111, "scale": 0.7, "min_depth_m": 2.0, "max_depth_m": 100.0,
     "min_disparity": -5},
    {"doffs_px": -3.0, "scale": 3.0, "invalid_value": 1, "max_depth_m": 1e39},
]  # fmt: skip


@pytest.mark.parametrize("isa", SIMD_ISAS)
@pytest.mark.parametrize("in_dtype", [np.float16, np.float32, np.float64, np.int16, np.uint16])
def test_depth_and_reprojection_options_match_baseline(isa: str, in_dtype: type) -> None:
    d = disparity_with_specials(in_dtype, (3, 7, 129), seed=np.dtype(in_dtype).num)
    for opts in DEPTH_OPTIONS:
        for out_dtype in (np.float32, np.uint16):
            o = DepthOptions(
                d, focal_px=718.856, baseline_m=0.537166, dtype=out_dtype,
                **{"min_depth_m": None, "max_depth_m": None, "invalid_value": None, **opts},
            )  # fmt: skip
            args = (o.focal_px, o.baseline_m, o.doffs_px, o.scale, o.min_depth_m, o.max_depth_m,
                    o.invalid_value, o.invalid_below)  # fmt: skip
            want, got = np.empty(d.shape, out_dtype), np.empty(d.shape, out_dtype)
            _core.disparity_to_depth(d, want, *args, 1, isa="baseline")
            _core.disparity_to_depth(d, got, *args, 3, isa=isa)
            np.testing.assert_array_equal(got, want, strict=True)
        q = np.array([[1, 0, 0, -300.5], [0, 1, 0, -200.25], [0, 0, 0, 718.856],
                      [0, 0, 1 / 0.537166, -0.3]]) + 1e-3  # fmt: skip
        r = ReprojectOptions(
            d, Q=q, focal_px=None, baseline_m=None, cx_px=None, cy_px=None, doffs_px=None,
            scale=opts["scale"], min_depth_m=opts.get("min_depth_m"),
            max_depth_m=opts.get("max_depth_m"), invalid_value=opts.get("invalid_value"),
            min_disparity=opts.get("min_disparity"),
        )  # fmt: skip
        arr = d.astype(np.float32) if in_dtype == np.float16 else d
        args2 = (r.Q, r.scale, r.min_depth_m, r.max_depth_m, r.invalid_value, r.invalid_below)
        want, got = np.empty((*d.shape, 3), np.float32), np.empty((*d.shape, 3), np.float32)
        _core.reproject(arr, want, *args2, 1, "baseline")
        _core.reproject(arr, got, *args2, 3, isa)
        np.testing.assert_array_equal(got, want, strict=True)
