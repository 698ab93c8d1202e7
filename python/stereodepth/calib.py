"""Reading calibration files: Middlebury's calib.txt."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["MiddleburyCalib", "read_middlebury_calib"]


@dataclass(frozen=True)
class MiddleburyCalib:
    """The fields of a Middlebury ``calib.txt`` (2014 and later format)."""

    cam0: np.ndarray  # 3x3 intrinsics of the left camera, pixels
    cam1: np.ndarray  # 3x3 intrinsics of the right camera, pixels
    doffs_px: float  # x difference of the principal points, cx1 - cx0
    baseline_mm: float
    width_px: int | None
    height_px: int | None
    ndisp: int | None  # a conservative bound on the number of disparity levels

    @property
    def focal_px(self) -> float:
        return float(self.cam0[0, 0])


def _matrix(text: str, key: str, path: Path) -> np.ndarray:
    rows = [r.split() for r in text.strip().strip("[]").split(";")]
    try:
        m = np.array([[float(v) for v in r] for r in rows], dtype=np.float64)
    except ValueError as exc:
        raise ValueError(f"{path}: {key} must be a 3x3 matrix, got {text!r}") from exc
    if m.shape != (3, 3):
        raise ValueError(f"{path}: {key} must be a 3x3 matrix, got {text!r}")
    return m


def read_middlebury_calib(path: str | os.PathLike[str]) -> MiddleburyCalib:
    """Parses a Middlebury ``calib.txt``: ``cam0=[f 0 cx; 0 f cy; 0 0 1]``, ``doffs=``,
    ``baseline=`` (mm), ``width=``, ``height=``, ``ndisp=``. Raises ValueError naming the file
    and the field when a required one is missing or malformed."""
    p = Path(path)
    fields: dict[str, str] = {}
    for line in p.read_text().splitlines():
        m = re.match(r"\s*([A-Za-z0-9_]+)\s*=\s*(.*?)\s*$", line)
        if m:
            fields[m.group(1)] = m.group(2)
    for key in ("cam0", "baseline"):
        if key not in fields:
            raise ValueError(f"{p}: missing field {key!r} in Middlebury calib.txt")

    def number(key: str, default: float | None = None) -> float | None:
        if key not in fields:
            return default
        try:
            return float(fields[key])
        except ValueError as exc:
            raise ValueError(f"{p}: {key} must be a number, got {fields[key]!r}") from exc

    def whole(key: str) -> int | None:
        v = number(key)
        return None if v is None else int(v)

    cam0 = _matrix(fields["cam0"], "cam0", p)
    cam1 = _matrix(fields["cam1"], "cam1", p) if "cam1" in fields else cam0.copy()
    baseline = number("baseline", 0.0) or 0.0
    if not baseline > 0:
        raise ValueError(f"{p}: baseline must be > 0 mm, got {fields['baseline']!r}")
    doffs = number("doffs", 0.0) or 0.0
    return MiddleburyCalib(
        cam0=cam0,
        cam1=cam1,
        doffs_px=doffs,
        baseline_mm=baseline,
        width_px=whole("width"),
        height_px=whole("height"),
        ndisp=whole("ndisp"),
    )
