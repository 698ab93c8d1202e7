"""A synthetic stereo pair with a known disparity, made by the package itself: for trying the
matcher, the web page's depth view and the ``match`` command without a camera or a download.

The scene is three fronto-parallel layers of random coloured texture, painted far to near: a
background wall, a disc and a box in front of it. The right image is the left one with every
layer shifted left by its own whole-pixel disparity, so the true disparity of every left
pixel is known exactly (:attr:`SamplePair.disparity`); disoccluded parts of the right image
show more of the background's texture.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _validate as check

__all__ = ["SAMPLE_BASELINE_MM", "SAMPLE_FOCAL_PX", "SamplePair", "sample_pair"]

#: The rig of the sample pair: focal length in pixels and baseline in millimetres (doffs 0).
SAMPLE_FOCAL_PX = 700.0
SAMPLE_BASELINE_MM = 120.0
#: Disparities of the layers, far to near: wall, disc, box (px).
LAYER_DISPARITIES_PX = (10, 20, 30)


@dataclass(frozen=True)
class SamplePair:
    """The pair, (H, W, 3) uint8 RGB each; the true disparity of the left image, (H, W) float32
    px; and the rig (``focal_px``, ``baseline_mm``, ``doffs_px``)."""

    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    focal_px: float = SAMPLE_FOCAL_PX
    baseline_mm: float = SAMPLE_BASELINE_MM
    doffs_px: float = 0.0


def _texture(rng: np.random.Generator, shape: tuple[int, int], base: np.ndarray) -> np.ndarray:
    """Random texture around ``base`` colour: noise smoothed by a 3x3 box, as float RGB."""
    h, w = shape
    noise = rng.random((h + 2, w + 2))
    smooth = sum(noise[i : i + h, j : j + w] for i in range(3) for j in range(3)) / 9.0
    shade = 0.6 + 1.6 * (smooth - 0.5) + 0.25 * (rng.random((h, w)) - 0.5)
    return np.clip(base[None, None, :] * shade[..., None], 0, 255)


def sample_pair(width: int = 320, height: int = 240, *, seed: int = 0) -> SamplePair:
    """The synthetic pair of ``width`` x ``height`` pixels (each at least 64), the same for
    the same ``seed``. Raises TypeError / ValueError naming a bad parameter."""
    w = check.integer("width", width, minimum=64, maximum=4096)
    h = check.integer("height", height, minimum=64, maximum=4096)
    s = check.integer("seed", seed, minimum=0)
    rng = np.random.default_rng(s)
    d_wall, d_disc, d_box = LAYER_DISPARITIES_PX
    pad = max(LAYER_DISPARITIES_PX) + 2
    canvas = (h, w + 2 * pad)  # texture coordinates: left column x is texture column x + pad

    yy, xx = np.mgrid[0:h, 0:w]
    disc = (xx - 0.33 * w) ** 2 + (yy - 0.45 * h) ** 2 <= (0.2 * min(w, h)) ** 2
    box = (np.abs(xx - 0.66 * w) <= 0.16 * w) & (np.abs(yy - 0.58 * h) <= 0.22 * h)
    layers = [
        (np.ones((h, w), dtype=bool), d_wall, np.array([150.0, 170.0, 200.0])),
        (disc, d_disc, np.array([230.0, 160.0, 60.0])),
        (box, d_box, np.array([90.0, 200.0, 110.0])),
    ]
    left = np.zeros((h, w, 3))
    right = np.zeros((h, w, 3))
    disparity = np.zeros((h, w), dtype=np.float32)
    cols = np.arange(w)
    for mask, d, colour in layers:
        tex = _texture(rng, canvas, colour)
        seen = tex[:, pad : pad + w]
        left[mask] = seen[mask]
        disparity[mask] = d
        # The right image sees texture column x + pad at x - d: column xr shows xr + d + pad.
        right_mask = np.zeros_like(mask)
        right_mask[:, : w - d] = mask[:, d:]
        if d == d_wall:  # the wall fills the whole right image (its texture is wider)
            right_mask[:] = True
        src = cols + d + pad
        shifted = tex[:, src]
        right[right_mask] = shifted[right_mask]
    return SamplePair(
        left=np.rint(left).astype(np.uint8),
        right=np.rint(right).astype(np.uint8),
        disparity=disparity,
    )
