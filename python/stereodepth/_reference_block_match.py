"""The numpy oracle of :func:`stereodepth.block_match` (re-exported by stereodepth.reference).

Plain, vectorised numpy that follows the steps documented in :mod:`stereodepth.matching` one
by one, with a full cost volume (H, W, num_disparities): fine for the crops the tests use, not
for speed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .matching import (
    CENSUS_WINDOW,
    PREFILTER_CAP,
    UINT16_STRETCH_TOP,
    BlockMatchOptions,
    check_channel_order,
    check_pair,
)

__all__ = ["block_match"]

_POPCOUNT8 = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


def grey(image: np.ndarray, *, channel_order: str = "rgb") -> np.ndarray:
    """int32 grey: the image itself, or OpenCV's fixed-point RGB -> grey for (H, W, 3)
    (``COLOR_RGB2GRAY``, or ``COLOR_BGR2GRAY`` for ``channel_order="bgr"``: the weights of
    red and blue trade places)."""
    if image.ndim == 3:
        c = image.astype(np.int32)
        w0, w2 = (9798, 3735) if check_channel_order(channel_order) == "rgb" else (3735, 9798)
        g: np.ndarray = (c[..., 0] * w0 + c[..., 1] * 19235 + c[..., 2] * w2 + 16384) >> 15
        return g
    return image.astype(np.int32)


def stretched(
    gl: np.ndarray, gr: np.ndarray, intensity_range: tuple[int, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A uint16 pair's int32 grey on the scale of uint8: ``lo`` and ``hi`` over both images
    (or ``intensity_range``, every value first clipped to it); every value ``v`` becomes
    ``((v - lo) * 65280 + (hi - lo) // 2) // (hi - lo)``; a constant pair is kept."""
    if intensity_range is None:
        lo = min(int(gl.min()), int(gr.min()))
        hi = max(int(gl.max()), int(gr.max()))
        if hi == lo:
            return gl, gr
    else:
        lo, hi = intensity_range
    span = np.int64(hi - lo)

    def one(g: np.ndarray) -> np.ndarray:
        v = (np.clip(g.astype(np.int64), lo, hi) - lo) * UINT16_STRETCH_TOP + span // 2
        out: np.ndarray = (v // span).astype(np.int32)
        return out

    return one(gl), one(gr)


def shifted(g: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """out[y, x] = g[clamp(y + dy), clamp(x + dx)]: the edge pixels repeat."""
    h, w = g.shape[:2]
    ys = np.clip(np.arange(h) + dy, 0, h - 1)
    xs = np.clip(np.arange(w) + dx, 0, w - 1)
    out: np.ndarray = g[ys][:, xs]
    return out


def census(g: np.ndarray, window: int = CENSUS_WINDOW) -> np.ndarray:
    """uint64 census codes over the border of the window (the 16 pixels two away from the
    centre for 5x5): one bit per neighbour, row-major, the first in the highest bit, set where
    the neighbour is darker than the centre."""
    half = window // 2
    code = np.zeros(g.shape, dtype=np.uint64)
    for dy in range(-half, half + 1):
        for dx in range(-half, half + 1):
            if max(abs(dy), abs(dx)) != half:
                continue
            code = (code << np.uint64(1)) | (shifted(g, dy, dx) < g).astype(np.uint64)
    return code


def popcount(x: np.ndarray) -> np.ndarray:
    """Set bits of each uint64, as int32."""
    x = np.ascontiguousarray(x, dtype=np.uint64)
    counts = _POPCOUNT8[x.view(np.uint8)].reshape(*x.shape, 8)
    total: np.ndarray = counts.sum(axis=-1, dtype=np.int32)
    return total


def sobel_x(g: np.ndarray, *, sixteen_bit: bool) -> np.ndarray:
    """The x-Sobel response (int32), shifted right by 8 bits for 16-bit images."""
    s: np.ndarray = (
        (shifted(g, -1, 1) - shifted(g, -1, -1))
        + 2 * (shifted(g, 0, 1) - shifted(g, 0, -1))
        + (shifted(g, 1, 1) - shifted(g, 1, -1))
    )
    return s >> 8 if sixteen_bit else s


def box_sum(c: np.ndarray, radius: int) -> np.ndarray:
    """Sum over the (2r+1) x (2r+1) block around each pixel of axes 0 and 1, the edge rows and
    columns repeating; int64."""
    pad = [(radius, radius), (radius, radius)] + [(0, 0)] * (c.ndim - 2)
    p = np.pad(c.astype(np.int64), pad, mode="edge")
    n = 2 * radius + 1
    s = np.cumsum(p, axis=0)
    s = np.concatenate([np.zeros_like(s[:1]), s], axis=0)
    rows = s[n:] - s[:-n]
    s = np.cumsum(rows, axis=1)
    s = np.concatenate([np.zeros_like(s[:, :1]), s], axis=1)
    return s[:, n:] - s[:, :-n]


def pixel_costs(
    gl: np.ndarray, gr: np.ndarray, o: BlockMatchOptions, *, sixteen_bit: bool
) -> np.ndarray:
    """c[y, x, k]: the cost of matching left (y, x) with right (y, clamp(x - d)), d = min + k."""
    h, w = gl.shape
    if o.cost == "census":
        fl, fr = census(gl), census(gr)
    else:
        cap = PREFILTER_CAP
        fl = np.clip(sobel_x(gl, sixteen_bit=sixteen_bit), -cap, cap) + cap
        fr = np.clip(sobel_x(gr, sixteen_bit=sixteen_bit), -cap, cap) + cap
    c = np.empty((h, w, o.num_disparities), dtype=np.int32)
    x = np.arange(w)
    for k in range(o.num_disparities):
        xr = np.clip(x - (o.min_disparity + k), 0, w - 1)
        if o.cost == "census":
            c[:, :, k] = popcount(fl ^ fr[:, xr])
        else:
            c[:, :, k] = np.abs(fl - fr[:, xr])
    return c


def speckle_filter(disp: np.ndarray, window: int, max_diff: float) -> np.ndarray:
    """NaN on 4-connected regions of at most `window` pixels (neighbours within max_diff)."""
    h, w = disp.shape
    valid = np.isfinite(disp)
    d64 = np.where(valid, disp, 0).astype(np.float32)
    # |a - b| in float32, compared with max_diff in float64, as the kernel does.
    east = (
        valid[:, :-1]
        & valid[:, 1:]
        & (np.abs(d64[:, 1:] - d64[:, :-1]).astype(np.float64) <= max_diff)
    )
    south = (
        valid[:-1, :]
        & valid[1:, :]
        & (np.abs(d64[1:, :] - d64[:-1, :]).astype(np.float64) <= max_diff)
    )
    # Every pixel's label converges to the least index in its region.
    labels = np.arange(h * w, dtype=np.int64).reshape(h, w)
    big = np.int64(h * w)
    while True:
        new = labels.copy()
        np.minimum(new[:, :-1], np.where(east, labels[:, 1:], big), out=new[:, :-1])
        np.minimum(new[:, 1:], np.where(east, labels[:, :-1], big), out=new[:, 1:])
        np.minimum(new[:-1, :], np.where(south, labels[1:, :], big), out=new[:-1, :])
        np.minimum(new[1:, :], np.where(south, labels[:-1, :], big), out=new[1:, :])
        new = new.ravel()[new]  # pointer jumping: a label's own label
        if np.array_equal(new, labels):
            break
        labels = new
    sizes = np.bincount(labels.ravel(), minlength=h * w)
    small = valid & (sizes[labels] <= window)
    out: np.ndarray = disp.copy()
    out[small] = np.nan
    return out


def block_match(
    left: Any,
    right: Any,
    *,
    num_disparities: int,
    **params: Any,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Oracle of :func:`stereodepth.block_match`: the same parameters, rules and tie-break
    (``threads`` is checked, then unused)."""
    o = BlockMatchOptions(num_disparities=num_disparities, **params)
    left_arr, right_arr = check_pair(left, right, o.check_size)
    sixteen_bit = left_arr.dtype == np.uint16
    gl = grey(left_arr, channel_order=o.channel_order)
    gr = grey(right_arr, channel_order=o.channel_order)
    if sixteen_bit:
        gl, gr = stretched(gl, gr, o.intensity_range)
    elif o.intensity_range is not None:
        raise ValueError(
            f"intensity_range applies to uint16 images (uint8 images are matched as they are), "
            f"got {o.intensity_range!r} with uint8 images"
        )
    h, w = gl.shape
    nd, dmin, r = o.num_disparities, o.min_disparity, o.block_size // 2
    ks = np.arange(nd)
    d_of_k = dmin + ks

    agg = box_sum(pixel_costs(gl, gr, o, sixteen_bit=sixteen_bit), r)  # (h, w, nd) int64

    # Candidates whose right pixel x - d lies in the image; the others never win.
    x = np.arange(w)
    xr_of = x[:, None] - d_of_k[None, :]
    cand_in = np.broadcast_to(((xr_of >= 0) & (xr_of <= w - 1))[None], (h, w, nd))
    sentinel = np.int64(1) << np.int64(62)
    agg_in = np.where(cand_in, agg, sentinel)

    # Winner: the least cost, the lowest disparity on a tie (argmin takes the first).
    kbest = np.argmin(agg_in, axis=2)
    best = np.take_along_axis(agg_in, kbest[..., None], axis=2)[..., 0]
    ok = best < sentinel  # some candidate inside the image
    if o.border == "opencv":
        # The whole search range must lie in the right image.
        ok &= ((x - (dmin + nd - 1)) >= 0) & ((x - dmin) <= w - 1)

    if o.texture_threshold > 0:
        grad = np.minimum(np.abs(sobel_x(gl, sixteen_bit=sixteen_bit)), PREFILTER_CAP)
        ok &= box_sum(grad, r).astype(np.float64) >= o.texture_sum_min

    # The least cost more than one disparity away from the winner (sentinel: none).
    far = np.abs(ks[None, None, :] - kbest[..., None]) > 1
    second = np.where(far, agg_in, sentinel).min(axis=2)
    has_second = second < sentinel
    if o.border == "clip":
        # The band's pixels whose candidates inside the image all lie within one disparity of
        # the winner (at most three, next to the edge): nothing to tell the winner from.
        ok &= has_second | cand_in.all(axis=2)
    if o.uniqueness_factor > 0:
        # best * factor may overflow to inf (a ratio near 1e308): no second cost passes then
        with np.errstate(over="ignore"):
            bound = best.astype(np.float64) * o.uniqueness_factor
        ok &= ~has_second | (second.astype(np.float64) * 100.0 > bound)

    if o.lr_max_diff is not None:
        # The right image's winner at xr: the least agg[xr + d, k] over d with xr + d in the
        # image, the lowest disparity on a tie.
        xl = x[:, None] + d_of_k[None, :]  # (w, nd): left column matching right column xr
        inside = (xl >= 0) & (xl <= w - 1)
        diag = agg[:, np.clip(xl, 0, w - 1), ks[None, :]]  # (h, w, nd)
        kright = np.argmin(np.where(inside[None], diag, sentinel), axis=2)
        xr = np.clip(x[None, :] - (dmin + kbest), 0, w - 1)
        kr_at = np.take_along_axis(kright, xr, axis=1)
        ok &= np.abs(kbest - kr_at).astype(np.float64) <= o.lr_max_diff

    disp = (dmin + kbest).astype(np.float32)
    if o.subpixel is not None and nd >= 3:
        # both neighbours are candidates inside the image
        lo_in = np.take_along_axis(cand_in, np.clip(kbest - 1, 0, nd - 1)[..., None], axis=2)
        hi_in = np.take_along_axis(cand_in, np.clip(kbest + 1, 0, nd - 1)[..., None], axis=2)
        interior = (kbest >= 1) & (kbest <= nd - 2) & lo_in[..., 0] & hi_in[..., 0]
        c0 = np.take_along_axis(agg, np.clip(kbest - 1, 0, nd - 1)[..., None], axis=2)[..., 0]
        c2 = np.take_along_axis(agg, np.clip(kbest + 1, 0, nd - 1)[..., None], axis=2)[..., 0]
        b = np.where(ok, best, 0)  # no sentinel arithmetic where there is no candidate
        num = (c0 - c2).astype(np.float32)
        if o.subpixel == "parabola":
            den = (2 * (c0 + c2 - 2 * b)).astype(np.float32)
        else:
            den = (2 * np.maximum(c0 - b, c2 - b)).astype(np.float32)
        use = interior & (den > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = np.where(use, num / np.where(use, den, np.float32(1)), np.float32(0))
        disp = disp + delta.astype(np.float32)
    disp = np.where(ok, disp, np.float32(np.nan)).astype(np.float32)

    if o.speckle_window > 0:
        disp = speckle_filter(disp, o.speckle_window, o.speckle_range)

    if not o.return_confidence:
        return np.asarray(disp)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (second - best).astype(np.float32) / second.astype(np.float32)
    conf = np.where(has_second, np.where(second > 0, ratio, np.float32(0)), np.float32(1))
    conf = np.where(np.isfinite(disp), conf, np.float32(0)).astype(np.float32)
    return np.asarray(disp), conf
