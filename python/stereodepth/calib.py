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


def _kitti_projections(p: Path) -> dict[int, tuple[int, np.ndarray]]:
    """The projection matrices of a KITTI calibration file: {camera: (line, 3x4 matrix)}.

    The format is one ``NAME: values`` per line (``P0:`` .. ``P3:`` in KITTI 2012's
    ``calib/*.txt``, ``P_rect_00:`` .. in 2015's ``calib_cam_to_cam/*.txt``, beside other
    names such as ``calib_time`` or ``Tr``, which are ignored). LF, CR LF or CR line ends,
    blank lines and surrounding spaces are accepted; the format has no comments, so any other
    line, a matrix that is not 12 finite numbers, or a camera given twice raises ValueError
    naming the file, the line and what was wrong."""
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{p}: not a KITTI calibration file (not UTF-8 text)") from exc
    mats: dict[int, tuple[int, np.ndarray]] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        m = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)", line)
        if m is None:
            raise ValueError(f"{p}:{lineno}: expected 'NAME: values', got {line!r}")
        key, values = m.groups()
        cam = re.fullmatch(r"P(\d)|P_rect_0(\d)", key)
        if cam is None:
            continue
        c = int(cam.group(1) or cam.group(2))
        try:
            vals = [float(v) for v in values.split()]
        except ValueError:
            raise ValueError(f"{p}:{lineno}: {key} must be 12 numbers, got {values!r}") from None
        if len(vals) != 12:
            raise ValueError(f"{p}:{lineno}: {key} must be 12 numbers, got {len(vals)}")
        if not np.isfinite(vals).all():
            raise ValueError(f"{p}:{lineno}: {key} must be 12 finite numbers, got {values!r}")
        if c in mats:
            raise ValueError(
                f"{p}:{lineno}: {key} gives camera {c} again (first on line {mats[c][0]})"
            )
        mats[c] = (lineno, np.array(vals, dtype=np.float64).reshape(3, 4))
    return mats


def read_kitti_calib(path: str | os.PathLike[str], cams: tuple[int, int] = (2, 3)) -> Calibration:
    """The rig of two rectified KITTI cameras from a calibration file (``P2: ...`` as in KITTI
    2012's ``calib/*.txt``, or ``P_rect_02: ...`` as in 2015's ``calib_cam_to_cam``): the
    left camera's focal length and principal point in pixels, the baseline in metres from the
    two projection matrices (B = (P_l[0,3] - P_r[0,3]) / f) and doffs = cx_r - cx_l.

    Source: A. Geiger et al., "Vision meets Robotics: The KITTI Dataset", IJRR 2013 (the
    devkit's readme for the file layout). Raises ValueError naming the file and what was
    wrong: a malformed line (the format is ``NAME: values`` per line, without comments; LF or
    CR LF line ends, blank lines and surrounding spaces are accepted), a matrix that is not 12
    finite numbers, a camera given twice, a missing camera, two cameras
    that are not a rectified pair (different focal lengths or rows), or a right camera that
    is not to the right of the left one."""
    p = Path(path)
    lc, rc = cams
    if lc == rc:
        raise ValueError(f"cams must be two different KITTI cameras, got {cams}")
    mats = _kitti_projections(p)
    for c in (lc, rc):
        if c not in mats:
            raise ValueError(f"{p}: missing P{c} (or P_rect_0{c}) in the KITTI calibration")
    pl, pr = mats[lc][1], mats[rc][1]
    f = float(pl[0, 0])
    if not f > 0:
        raise ValueError(f"{p}: P{lc} focal length must be > 0, got {f}")
    for name, a, b in (
        ("focal length fx", pl[0, 0], pr[0, 0]),
        ("focal length fy", pl[1, 1], pr[1, 1]),
        ("principal point row cy", pl[1, 2], pr[1, 2]),
    ):
        if abs(a - b) > 1e-6 * max(abs(a), abs(b)) + 1e-9:
            raise ValueError(
                f"{p}: P{lc} and P{rc} are not a rectified pair: their {name} differ ({a} and {b})"
            )
    if not (np.array_equal(pl[2, :3], [0, 0, 1]) and np.array_equal(pr[2, :3], [0, 0, 1])):
        raise ValueError(
            f"{p}: P{lc} and P{rc} must end in a row 0 0 1 t (rectified projection matrices)"
        )
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
