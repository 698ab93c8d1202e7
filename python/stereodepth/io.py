"""Reading and writing images and maps: PNG (8/16-bit), PFM, and atomic writes.

Needs Pillow for PNG (the ``batch`` extra): ``pip install "stereodepth[batch]"``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["read_image"]


def _pil() -> Any:
    try:
        from PIL import Image
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            'reading images needs Pillow: pip install "stereodepth[batch]"'
        ) from exc
    return Image


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """An image file as a numpy array: (H, W) uint8 or uint16 grey, or (H, W, 3) uint8 RGB.

    Palette and grey-alpha images become grey or RGB; an alpha channel is dropped. Raises
    FileNotFoundError for a missing file and ValueError naming the file when it cannot be
    decoded."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"image not found: {p}")
    Image = _pil()
    try:
        with Image.open(p) as im:
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I;16L"):
                return np.asarray(im, dtype=np.uint16)
            if mode == "I":
                arr = np.asarray(im)
                if arr.min() < 0 or arr.max() > 65535:
                    raise ValueError(f"{p}: 32-bit image values outside 0..65535")
                return arr.astype(np.uint16)
            if mode == "L":
                return np.asarray(im, dtype=np.uint8)
            if mode in ("1", "P", "LA", "PA"):
                im2 = im.convert("RGBA" if mode in ("P", "PA") else "L")
                if im2.mode == "RGBA":
                    rgb = np.asarray(im2.convert("RGB"), dtype=np.uint8)
                    if (rgb[..., 0] == rgb[..., 1]).all() and (rgb[..., 1] == rgb[..., 2]).all():
                        return np.ascontiguousarray(rgb[..., 0])
                    return rgb
                return np.asarray(im2, dtype=np.uint8)
            return np.asarray(im.convert("RGB"), dtype=np.uint8)
    except (OSError, SyntaxError) as exc:  # Pillow's errors for truncated / corrupt files
        raise ValueError(f"cannot decode image {p}: {exc}") from exc
