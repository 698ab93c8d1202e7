"""Synthetic stereo pairs with a known disparity, shared by the matchers' tests."""

from __future__ import annotations

from typing import Any

import numpy as np


def shifted_pair(
    shape: tuple[int, int], shift: int, *, seed: int, dtype: Any = np.uint8, rgb: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """A random-dot stereogram: left[y, x] = right[y, x - shift]."""
    rng = np.random.default_rng(seed)
    h, w = shape
    top = 65536 if dtype == np.uint16 else 256
    extra = abs(shift)
    size = (h, w + extra, 3) if rgb else (h, w + extra)
    canvas = rng.integers(0, top, size=size).astype(dtype)
    m = max(0, -shift)
    left = canvas[:, m : m + w]
    right = canvas[:, m + shift : m + shift + w]
    return np.ascontiguousarray(left), np.ascontiguousarray(right)


def slanted_pair(
    shape: tuple[int, int], *, d0: float, dx: float, dy: float, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A textured slanted plane: disparity d0 + dx * x + dy * y (sub-pixel), left sampled
    from the right image by linear interpolation along each row."""
    rng = np.random.default_rng(seed)
    h, w = shape
    # Smooth-ish texture so interpolation is meaningful.
    base = rng.random((h, w + 8)) * 255
    base = (base + np.roll(base, 1, axis=1) + np.roll(base, 1, axis=0)) / 3
    right = base[:, :w]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    disp = d0 + dx * xs + dy * ys
    left = np.empty((h, w))
    cols = np.arange(w + 8, dtype=np.float64)
    for y in range(h):
        left[y] = np.interp(xs[y] - disp[y], cols, base[y])
    return left.round().astype(np.uint8), right.round().astype(np.uint8), disp.astype(np.float32)
