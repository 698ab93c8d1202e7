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


# --- KITTI calibration files, and a rectified rig from any calibration file -------------------
# (the rig that ``stereodepth batch`` computes each pair with)
__all__ += ["Calibration", "read_calibration", "read_kitti_calib"]


@dataclass(frozen=True)
class Calibration:
    """A rectified rig: depth = focal_px * baseline_m / (d + doffs_px)."""

    focal_px: float
    baseline_m: float
    doffs_px: float = 0.0
    cx_px: float | None = None  # the left camera's principal point; None: the image centre
    cy_px: float | None = None
    num_disparities: int | None = None  # Middlebury's ndisp, when the file has it
    source: str = ""

    def as_dict(self) -> dict[str, float | int | str | None]:
        return {
            "focal_px": self.focal_px,
            "baseline_m": self.baseline_m,
            "doffs_px": self.doffs_px,
            "cx_px": self.cx_px,
            "cy_px": self.cy_px,
            "num_disparities": self.num_disparities,
            "source": self.source,
        }


def read_kitti_calib(path: str | os.PathLike[str], cams: tuple[int, int] = (2, 3)) -> Calibration:
    """The rig of two rectified KITTI cameras from a calibration file (``P2: ...`` as in KITTI
    2012's ``calib/*.txt``, or ``P_rect_02: ...`` as in 2015's ``calib_cam_to_cam``)."""
    p = Path(path)
    mats: dict[int, np.ndarray] = {}
    for line in p.read_text().splitlines():
        m = re.match(r"\s*P(?:_rect_)?0?(\d)\s*:\s*(.*)$", line)
        if not m:
            continue
        try:
            vals = [float(v) for v in m.group(2).split()]
        except ValueError as exc:
            raise ValueError(f"{p}: P{m.group(1)} must be 12 numbers, got {m.group(2)!r}") from exc
        if len(vals) != 12:
            raise ValueError(f"{p}: P{m.group(1)} must be 12 numbers, got {len(vals)}")
        mats[int(m.group(1))] = np.array(vals).reshape(3, 4)
    lc, rc = cams
    for c in (lc, rc):
        if c not in mats:
            raise ValueError(f"{p}: missing P{c} (or P_rect_0{c}) in the KITTI calibration")
    pl, pr = mats[lc], mats[rc]
    f = float(pl[0, 0])
    if not f > 0:
        raise ValueError(f"{p}: P{lc} focal length must be > 0, got {f}")
    baseline = float(pl[0, 3] - pr[0, 3]) / f
    if not baseline > 0:
        raise ValueError(
            f"{p}: camera {rc} must be right of camera {lc}, got a baseline of {baseline} m"
        )
    return Calibration(
        focal_px=f,
        baseline_m=baseline,
        doffs_px=float(pr[0, 2] - pl[0, 2]),
        cx_px=float(pl[0, 2]),
        cy_px=float(pl[1, 2]),
        source=str(p),
    )


def read_calibration(
    path: str | os.PathLike[str], cams: tuple[int, int] | None = None
) -> Calibration:
    """A Middlebury ``calib.txt`` or a KITTI calibration file, told apart by their content."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"calibration file not found: {p}")
    text = p.read_text(errors="replace")
    if re.search(r"^\s*P(_rect_0)?\d\s*:", text, flags=re.MULTILINE):
        return read_kitti_calib(p, cams or (2, 3))
    c = read_middlebury_calib(p)
    return Calibration(
        focal_px=c.focal_px,
        baseline_m=c.baseline_mm / 1000.0,
        doffs_px=c.doffs_px,
        cx_px=float(c.cam0[0, 2]),
        cy_px=float(c.cam0[1, 2]),
        num_disparities=c.ndisp,
        source=str(p),
    )
