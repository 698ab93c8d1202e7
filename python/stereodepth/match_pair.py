"""One stereo pair to disparity and depth, the steps shared by ``stereodepth match`` and the web
page's depth view: make the pair comparable, run the chosen matcher, convert to depth with
the rig, and sum the result up.

Rules where images differ, the same as :func:`stereodepth.block_match` and ``stereodepth
batch``: a colour and a grey image, images of different sizes or of different bit depths are
refused. The default number of disparities is a Middlebury ``ndisp`` when the calibration has
one, else :func:`default_num_disparities` of the width.
"""

from __future__ import annotations

import inspect
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import _validate as check
from ._methods import METHODS, check_method

__all__ = [
    "METHODS",
    "MatchResult",
    "default_num_disparities",
    "kitti_cameras",
    "match_pair",
    "prepare_pair",
    "read_calibration_file",
    "sgm_available",
]


def sgm_available() -> bool:
    """Whether this version of the library has ``stereodepth.semi_global_match``."""
    import stereodepth

    return hasattr(stereodepth, "semi_global_match")


def default_num_disparities(width_px: int) -> int:
    """A search range for an image ``width_px`` wide when nothing better is known: an eighth of
    the width rounded up to a multiple of 16, from 16 to 256 px (for a 640 px image, 80).
    Raises TypeError or ValueError unless ``width_px`` is an integer >= 1 (a float width was
    Python's TypeError or OverflowError, naming nothing, or a range for a width of -5)."""
    width = check.integer("width_px", width_px, minimum=1)
    return int(min(256, max(16, math.ceil(width / 8 / 16) * 16)))


def read_calibration_file(path: str | os.PathLike[str], cams: tuple[int, int] | None = None) -> Any:
    """A Middlebury ``calib.txt`` or a KITTI calibration file, with the library's reader (its
    result has ``focal_px``, ``baseline_m``, ``doffs_px``, ``cx_px``, ``cy_px`` and
    ``num_disparities``); ``cams`` the KITTI cameras (default (2, 3), the colour pair). Raises
    FileNotFoundError or ValueError naming the file."""
    from . import calib

    reader: Any = getattr(calib, "read_calibration", None)
    if reader is None:  # the KITTI reader still lives beside the batch command
        from . import batch

        reader = batch.read_calibration
    return reader(path, cams)


def kitti_cameras(left: str | os.PathLike[str], right: str | os.PathLike[str]) -> Any:
    """The KITTI cameras of a pair by its images' folders, as ``stereodepth batch`` tells
    them: ``image_0``/``image_1`` (the grey pair) (0, 1), ``image_2``/``image_3`` (2, 3);
    None for any other folders."""
    from .batch.discovery import folder_cameras

    return folder_cameras(Path(left), Path(right))


def prepare_pair(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pair as the matcher takes it, checked by the rule :func:`stereodepth.block_match`
    and ``stereodepth batch`` follow: the same size, both colour or both grey, the same bit
    depth. Raises TypeError naming the image that is not a numpy array, ValueError naming the
    one that is not (H, W) or (H, W, C), and ValueError naming ``right`` (the one compared)
    when they differ."""
    for name, image in (("left", left), ("right", right)):
        # a list or a path was an AttributeError ('list' object has no attribute 'shape'), a
        # 1-D array an IndexError from the size message
        if not isinstance(image, np.ndarray):
            raise TypeError(f"{name} must be a numpy.ndarray image, got {type(image).__name__}")
        check.not_masked(name, image)
        if image.ndim not in (2, 3):
            raise ValueError(
                f"{name} must be an image, (H, W) grey or (H, W, 3) colour, got shape {image.shape}"
            )
    if left.shape[:2] != right.shape[:2]:
        raise ValueError(
            f"right must have the size of left, {left.shape[1]}x{left.shape[0]} px, got "
            f"{right.shape[1]}x{right.shape[0]} px"
        )
    if left.ndim != right.ndim:

        def kind(a: np.ndarray) -> str:
            return "colour (RGB)" if a.ndim == 3 else "grey"

        raise ValueError(
            f"right must be {kind(left)} as left is, got a {kind(right)} image (convert one "
            "of them: both colour or both grey)"
        )
    if left.dtype != right.dtype:
        bits = {np.dtype(np.uint8): "8-bit", np.dtype(np.uint16): "16-bit"}
        raise ValueError(
            f"right must have the bit depth of left ({bits.get(left.dtype, left.dtype)}), got "
            f"{bits.get(right.dtype, right.dtype)}"
        )
    return left, right


@dataclass
class MatchResult:
    """What :func:`match_pair` computed: ``disparity`` (H, W) float32 px, NaN where unknown;
    ``confidence`` (H, W) float32 in [0, 1] or None (a matcher without one); ``depth`` (H, W)
    float32 m from ``disparity_to_depth`` with the rig, or None without one; ``time_s`` the
    matcher's wall time; ``params`` the matcher's settings."""

    disparity: np.ndarray
    confidence: np.ndarray | None
    depth: np.ndarray | None
    time_s: float
    method: str
    params: dict[str, Any] = field(default_factory=dict)
    focal_px: float | None = None
    baseline_m: float | None = None
    doffs_px: float = 0.0

    def summary(self) -> dict[str, Any]:
        """JSON-ready numbers: size, search range, density (the fraction of pixels with a
        disparity), disparity and depth ranges (min and max of the valid values, null when
        none), time."""
        h, w = self.disparity.shape
        ok = np.isfinite(self.disparity)
        out: dict[str, Any] = {
            "width": w,
            "height": h,
            "method": self.method,
            "num_disparities": self.params.get("num_disparities"),
            "min_disparity": self.params.get("min_disparity", 0),
            "params": self.params,
            "density": float(ok.mean()),
            "disparity_range_px": _range(self.disparity),
            "depth_range_m": None if self.depth is None else _range(self.depth),
            "time_s": self.time_s,
        }
        if self.focal_px is not None:
            out["rig"] = {
                "focal_px": self.focal_px,
                "baseline_m": self.baseline_m,
                "doffs_px": self.doffs_px,
            }
        return out


def _range(a: np.ndarray) -> list[float] | None:
    ok = np.isfinite(a)
    if not ok.any():
        return None
    return [float(a[ok].min()), float(a[ok].max())]


def match_pair(
    left: np.ndarray,
    right: np.ndarray,
    *,
    method: str = "bm",
    num_disparities: int | None = None,
    min_disparity: int = 0,
    block_size: int | None = None,
    cost: str | None = None,
    focal_px: float | None = None,
    baseline_m: float | None = None,
    doffs_px: float = 0.0,
    threads: int | None = None,
) -> MatchResult:
    """Disparity (and depth, given ``focal_px`` and ``baseline_m``) of a rectified pair.

    ``method`` is ``"bm"`` (:func:`stereodepth.block_match`, with its confidence) or ``"sgm"``
    (``stereodepth.semi_global_match``, where the library has it). ``num_disparities``
    defaults to :func:`default_num_disparities` of the width; ``block_size`` and ``cost`` to
    the block matcher's defaults. Depth is ``disparity_to_depth(disparity, focal_px=...,
    baseline_m=..., doffs_px=...)``, float32 metres, given both ``focal_px`` and
    ``baseline_m`` (one without the other, or a non-zero ``doffs_px`` without them, is a
    ValueError: there would be no depth). Raises ValueError or TypeError naming the
    parameter."""
    import stereodepth

    if (focal_px is None) != (baseline_m is None):
        # one without the other gave no depth without a word
        given, got = ("focal_px", focal_px) if baseline_m is None else ("baseline_m", baseline_m)
        missing = "baseline_m" if baseline_m is None else "focal_px"
        raise ValueError(
            f"focal_px and baseline_m go together: {missing} missing (got {given}={got!r}); "
            "give both for depth, or neither for the disparity alone"
        )
    if focal_px is None and doffs_px != 0:
        raise ValueError(
            f"doffs_px applies with focal_px and baseline_m (the depth), got doffs_px="
            f"{doffs_px!r} without them"
        )
    check_method(method)  # TypeError for a list or None (was ValueError), ValueError else
    left, right = prepare_pair(left, right)
    nd = default_num_disparities(left.shape[1]) if num_disparities is None else num_disparities
    params: dict[str, Any] = {"num_disparities": nd, "min_disparity": min_disparity}
    confidence: np.ndarray | None = None
    if method == "bm":
        if block_size is not None:
            params["block_size"] = block_size
        if cost is not None:
            params["cost"] = cost
        t0 = time.perf_counter()
        disparity, confidence = stereodepth.block_match(
            left, right, return_confidence=True, threads=threads, **params
        )
        elapsed = time.perf_counter() - t0
        from .matching import DEFAULT_BLOCK_SIZE

        params.setdefault("block_size", DEFAULT_BLOCK_SIZE)
        params.setdefault("cost", "census")
    else:
        if not sgm_available():
            raise ValueError(
                "method 'sgm' needs stereodepth.semi_global_match, which this version of the "
                "library does not have; use method 'bm'"
            )
        sgm = stereodepth.semi_global_match
        # The options it takes (block_size, threads, confidence) are passed where it has them.
        accepted = inspect.signature(sgm).parameters
        for name, value in (("block_size", block_size), ("cost", cost)):
            if value is None:
                continue
            if name not in accepted:
                raise ValueError(
                    f"{name} is an option of method 'bm'; method 'sgm' has no {name}, got {value!r}"
                )
            params[name] = value
        extra: dict[str, Any] = {}
        if "threads" in accepted:
            extra["threads"] = threads
        if "return_confidence" in accepted:
            extra["return_confidence"] = True
        t0 = time.perf_counter()
        out = sgm(left, right, **params, **extra)
        elapsed = time.perf_counter() - t0
        if isinstance(out, tuple):
            disparity = out[0]
            confidence = out[1] if len(out) > 1 else None
        else:
            disparity = out
        # The summary says the block it used, as for "bm": the given one, else its default.
        if (
            "block_size" in accepted
            and accepted["block_size"].default is not inspect.Parameter.empty
        ):
            params.setdefault("block_size", accepted["block_size"].default)
    disparity = np.asarray(disparity, dtype=np.float32)
    depth = None
    if focal_px is not None and baseline_m is not None:
        depth = stereodepth.disparity_to_depth(
            disparity, focal_px=focal_px, baseline_m=baseline_m, doffs_px=doffs_px
        )
    return MatchResult(
        disparity=disparity,
        confidence=confidence,
        depth=depth,
        time_s=elapsed,
        method=method,
        params=params,
        focal_px=focal_px,
        baseline_m=baseline_m,
        doffs_px=doffs_px,
    )
