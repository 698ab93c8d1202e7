"""The numpy oracle of :func:`stereodepth.semi_global_match` (re-exported by
stereodepth.reference).

Plain numpy following the steps documented in :mod:`stereodepth.semi_global` one by one, with
full (H, W, num_disparities) volumes and one loop step per row or column of each path: fine
for the crops the tests use, not for speed. The stages the block matcher shares (grey,
census, box sums, speckle filter) come from its oracle.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._reference_block_match import box_sum, census, grey, popcount, speckle_filter
from .matching import as_pair
from .semi_global import (
    SemiGlobalOptions,
    cost_max,
    fill_background,
    run_disparities,
    stripe_starts,
)

__all__ = ["semi_global_match"]

#: The path directions (dy, dx): the previous pixel on the path is (y - dy, x - dx).
PATHS_3 = ((0, 1), (0, -1), (1, 0))
PATHS_4 = (*PATHS_3, (-1, 0))
PATHS_8 = (*PATHS_4, (1, 1), (1, -1), (-1, 1), (-1, -1))


def candidate_inside(w: int, min_disparity: int, num_disparities: int) -> np.ndarray:
    """(W, nd) bool: the right pixel x - d of candidate d lies inside the image."""
    xr = np.arange(w)[:, None] - (min_disparity + np.arange(num_disparities))[None, :]
    inside: np.ndarray = (xr >= 0) & (xr <= w - 1)
    return inside


def costs(gl: np.ndarray, gr: np.ndarray, o: SemiGlobalOptions, nd: int) -> np.ndarray:
    """C[y, x, k] for k < nd: box sums of the census Hamming distances, candidates outside
    the right image at the largest cost (int64)."""
    h, w = gl.shape
    fl, fr = census(gl), census(gr)
    pix = np.empty((h, w, nd), dtype=np.int64)
    x = np.arange(w)
    for k in range(nd):
        xr = np.clip(x - (o.min_disparity + k), 0, w - 1)
        pix[:, :, k] = popcount(fl ^ fr[:, xr])
    c = box_sum(pix, o.block_size // 2)
    inside = candidate_inside(w, o.min_disparity, nd)
    out: np.ndarray = np.where(inside[None], c, np.int64(cost_max(o.block_size)))
    return out


def _step(
    lp: np.ndarray, c: np.ndarray, ip: np.ndarray, iq: np.ndarray, o: SemiGlobalOptions
) -> np.ndarray:
    """L(p, .) from the previous pixel's L(q, .) (both (n, nd)), C(p, .) and the grey levels of
    p and q (n,)."""
    s = np.abs(ip - iq)
    if o.p2_step > 0:
        p2 = np.maximum(o.p1, (o.p2 * o.p2_step) // (o.p2_step + s))
    else:
        p2 = np.full(s.shape, o.p2, dtype=np.int64)
    m = lp.min(axis=1, keepdims=True)
    best = np.minimum(lp, m + p2[:, None])
    best[:, 1:] = np.minimum(best[:, 1:], lp[:, :-1] + o.p1)
    best[:, :-1] = np.minimum(best[:, :-1], lp[:, 1:] + o.p1)
    out: np.ndarray = c + best - m
    return out


def path_costs(
    c: np.ndarray,
    g: np.ndarray,
    dy: int,
    dx: int,
    o: SemiGlobalOptions,
    restarts: frozenset[int] = frozenset(),
) -> np.ndarray:
    """L_r for the direction (dy, dx), in scan order (int64, like c); a downward path starts
    again at every row in ``restarts``."""
    h, w, _ = c.shape
    lr = np.empty_like(c)
    if dy == 0:
        xs = range(w) if dx == 1 else range(w - 1, -1, -1)
        for i, x in enumerate(xs):
            if i == 0:
                lr[:, x] = c[:, x]
            else:
                lr[:, x] = _step(lr[:, x - dx], c[:, x], g[:, x], g[:, x - dx], o)
        return lr
    ys = range(h) if dy == 1 else range(h - 1, -1, -1)
    xq = np.arange(w) - dx  # the previous pixel's column
    has = (xq >= 0) & (xq <= w - 1)
    xqc = np.clip(xq, 0, w - 1)
    for i, y in enumerate(ys):
        if i == 0 or y in restarts:
            lr[y] = c[y]
            continue
        q = y - dy
        stepped = _step(lr[q][xqc], c[y], g[y], g[q][xqc], o)
        lr[y] = np.where(has[:, None], stepped, c[y])
    return lr


def median3(disp: np.ndarray) -> np.ndarray:
    """Each valid pixel: the lower median of the valid pixels of its 3x3 window inside the
    image; NaN stays NaN."""
    h, w = disp.shape
    p = np.pad(disp, 1, constant_values=np.nan)
    stack = np.stack([p[dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)], axis=-1)
    srt = np.sort(stack, axis=-1)  # NaN last
    n = np.isfinite(stack).sum(axis=-1)
    idx = np.maximum(n - 1, 0) // 2
    med = np.take_along_axis(srt, idx[..., None], axis=-1)[..., 0]
    out: np.ndarray = np.where(np.isfinite(disp), med, np.float32(np.nan)).astype(np.float32)
    return out


def semi_global_match(
    left: Any,
    right: Any,
    *,
    num_disparities: int,
    **params: Any,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Oracle of :func:`stereodepth.semi_global_match`: the same parameters, rules and
    tie-breaks (``threads`` and ``max_memory_mb`` are checked, then unused)."""
    o = SemiGlobalOptions(num_disparities=num_disparities, **params)
    left_arr, right_arr = as_pair(
        left,
        right,
        channel_order=o.channel_order,
        intensity_range=o.intensity_range,
        check_size=o.check_size,
    )
    gl = grey(left_arr, channel_order=o.channel_order)
    gr = grey(right_arr, channel_order=o.channel_order)
    ig = gl.astype(np.int64)
    if left_arr.dtype == np.uint16:
        ig = ig >> 8  # grey levels on the 8-bit scale for the P2 adaptation
    h, w = gl.shape
    nd, dmin = o.num_disparities, o.min_disparity
    ks = np.arange(nd)
    d_of_k = dmin + ks

    # The paths run over run_disparities(nd) >= nd candidates; only the first nd may win.
    c = costs(gl, gr, o, run_disparities(nd))
    dirs = {3: PATHS_3, 4: PATHS_4, 8: PATHS_8}[o.paths]
    restarts = frozenset(stripe_starts(h)) if o.paths == 3 else frozenset()
    s = np.zeros_like(c)
    for dy, dx in dirs:
        s += path_costs(c, ig, dy, dx, o, restarts)
    s = s[:, :, :nd]

    inside = np.broadcast_to(candidate_inside(w, dmin, nd)[None], (h, w, nd))
    sentinel = np.int64(1) << np.int64(40)
    sv = np.where(inside, s, sentinel)
    kbest = np.argmin(sv, axis=2)
    best = np.take_along_axis(sv, kbest[..., None], axis=2)[..., 0]
    ok = best < sentinel
    if o.border == "opencv":
        x = np.arange(w)
        ok &= ((x - (dmin + nd - 1)) >= 0) & ((x - dmin) <= w - 1)

    far = np.abs(ks[None, None, :] - kbest[..., None]) > 1
    second = np.where(far, sv, sentinel).min(axis=2)
    has_second = second < sentinel
    if o.border == "clip":
        # The band's pixels whose candidates inside the image all lie within one disparity of
        # the winner (at most three, next to the edge): nothing to tell the winner from.
        ok &= has_second | inside.all(axis=2)
    if o.uniqueness_factor > 0:
        # best * factor may overflow to inf (a ratio near 1e308): no second cost passes then
        with np.errstate(over="ignore"):
            bound = best.astype(np.float64) * o.uniqueness_factor
        ok &= ~has_second | (second.astype(np.float64) * 100.0 > bound)

    if o.lr_max_diff is not None:
        x = np.arange(w)
        xl = x[:, None] + d_of_k[None, :]
        lin = (xl >= 0) & (xl <= w - 1)
        diag = s[:, np.clip(xl, 0, w - 1), ks[None, :]]
        kright = np.argmin(np.where(lin[None], diag, sentinel), axis=2)
        xr = np.clip(x[None, :] - (dmin + kbest), 0, w - 1)
        kr_at = np.take_along_axis(kright, xr, axis=1)
        ok &= np.abs(kbest - kr_at).astype(np.float64) <= o.lr_max_diff

    disp = (dmin + kbest).astype(np.float32)
    if o.subpixel is not None:
        lo_in = np.take_along_axis(inside, np.clip(kbest - 1, 0, nd - 1)[..., None], axis=2)
        hi_in = np.take_along_axis(inside, np.clip(kbest + 1, 0, nd - 1)[..., None], axis=2)
        interior = (kbest >= 1) & (kbest <= nd - 2) & lo_in[..., 0] & hi_in[..., 0]
        c0 = np.take_along_axis(s, np.clip(kbest - 1, 0, nd - 1)[..., None], axis=2)[..., 0]
        c2 = np.take_along_axis(s, np.clip(kbest + 1, 0, nd - 1)[..., None], axis=2)[..., 0]
        b = np.where(ok, best, 0)
        num = (c0 - c2).astype(np.float32)
        if o.subpixel == "parabola":
            den = (2 * (c0 + c2 - 2 * b)).astype(np.float32)
        else:
            den = (2 * np.maximum(c0 - b, c2 - b)).astype(np.float32)
        use = interior & (den > 0) & ok
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = np.where(use, num / np.where(use, den, np.float32(1)), np.float32(0))
        disp = disp + delta.astype(np.float32)
    disp = np.where(ok, disp, np.float32(np.nan)).astype(np.float32)

    if o.median:
        disp = median3(disp)
    if o.speckle_window > 0:
        disp = speckle_filter(disp, o.speckle_window, o.speckle_range)
    conf_valid = np.isfinite(disp)
    if o.fill:
        disp = fill_background(disp.copy())

    if not o.return_confidence:
        return np.asarray(disp)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (second - best).astype(np.float32) / second.astype(np.float32)
    conf = np.where(has_second, np.where(second > 0, ratio, np.float32(0)), np.float32(1))
    conf = np.where(conf_valid, conf, np.float32(0)).astype(np.float32)
    return np.asarray(disp), conf
