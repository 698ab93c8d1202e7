"""Middlebury's ``calib.txt`` (the 2014 format: cam0, cam1, doffs, baseline, width, height,
ndisp; D. Scharstein et al., GCPR 2014)."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._common import (
    _INTEGER_RE,
    _LINE_RE,
    _NUMBER_RE,
    _differ,
    _image_size_of,
    _path,
    _read_text,
    _shown,
)
from .stereo import StereoCalibration, _rectified_calibration

__all__ = ["MiddleburyCalib", "read_middlebury_calib", "read_middlebury_stereo_calibration"]

#: More digits than any width, height or ndisp has (int() refuses over 4300).
_MAX_DIGITS = 18


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


#: How far (px) ``doffs`` may be from cam1's cx - cam0's cx: the files print both to three
#: decimals, so the two differ by at most 0.0015 px in a consistent file.
DOFFS_TOLERANCE_PX = 0.01


def _matrix(text: str, key: str, path: Path) -> np.ndarray:
    """``[a b c; d e f; g h i]``: a 3x3 intrinsics matrix, finite, positive focal lengths,
    last row 0 0 1."""
    rule = f"{key} must be a 3x3 matrix [fx 0 cx; 0 fy cy; 0 0 1]"
    m = re.fullmatch(r"\[(.*)\]", text)
    rows = m.group(1).split(";") if m else []
    cells = [r.split() for r in rows]
    if len(cells) != 3 or any(len(r) != 3 for r in cells):
        raise ValueError(f"{path}: {rule}, got {text!r}")
    if not all(_NUMBER_RE.fullmatch(v) for r in cells for v in r):
        raise ValueError(f"{path}: {rule} of numbers, got {text!r}")
    k = np.array([[float(v) for v in r] for r in cells], dtype=np.float64)
    if not np.isfinite(k).all():
        raise ValueError(f"{path}: {key} must be finite, got {text!r}")
    if not (k[0, 0] > 0 and k[1, 1] > 0):
        raise ValueError(f"{path}: {key} focal lengths must be > 0, got {text!r}")
    if k[2].tolist() != [0.0, 0.0, 1.0] or k[1, 0] != 0:
        raise ValueError(f"{path}: {key}'s last row must be 0 0 1, got {text!r}")
    if k[0, 1] != 0:  # a rectified view has no skew; it was ignored, as if it were 0
        raise ValueError(f"{path}: {key} must have no skew (its [0, 1] entry 0), got {text!r}")
    return k


def read_middlebury_calib(path: str | os.PathLike[str]) -> MiddleburyCalib:
    """Parses a Middlebury ``calib.txt`` (the 2014 format, vision.middlebury.edu/stereo/data/
    scenes2014): one ``key=value`` a line, ``cam0=[f 0 cx; 0 f cy; 0 0 1]``, ``cam1=``,
    ``doffs=`` (px), ``baseline=`` (mm), ``width=``, ``height=``, ``ndisp=``, and keys this
    reader does not use (``isint``, ``vmin``, ``vmax``, ``dyavg``, ``dymax``, ...).

    Line ends LF, CR LF or CR; spaces around ``=`` and at line ends; blank lines. The format
    has no comments: any other line is refused. ``cam0`` and ``baseline`` are required.
    ``doffs`` is by definition cam1's cx - cam0's cx: without ``cam1``, cam1 is cam0 with cx
    shifted by ``doffs``; without ``doffs``, it is that difference (0 when both are missing).

    Raises FileNotFoundError for a missing file and ValueError naming the file and the field
    (with the line number for a malformed line): a line that is not ``key=value``, a key
    given twice, a missing required key, a matrix that is not 3x3 with finite numbers,
    positive focal lengths, no skew and a last row 0 0 1, a cam1 whose fx, fy or cy differ
    from cam0's (not a rectified pair), a baseline that is not a finite number
    > 0, a non-finite doffs or one that differs from cam1's cx - cam0's cx by more than
    ``DOFFS_TOLERANCE_PX``, a width, height or ndisp that is not a whole number > 0, a width
    without a height or the other way round."""
    p = _path(path)
    text = _read_text(p, "Middlebury calib.txt")
    fields: dict[str, str] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        m = _LINE_RE.fullmatch(line.strip(" \t"))
        if m is None:
            raise ValueError(
                f"{p}: line {lineno} of a Middlebury calib.txt must be key=value, got {line!r}"
            )
        key, value = m.groups()
        if key in fields:
            raise ValueError(f"{p}: {key} is given twice (line {lineno})")
        fields[key] = value
    for key in ("cam0", "baseline"):
        if key not in fields:
            raise ValueError(f"{p}: missing field {key!r} in Middlebury calib.txt")

    def number(key: str) -> float:
        v = fields[key]
        if _NUMBER_RE.fullmatch(v) is None or not np.isfinite(float(v)):
            raise ValueError(f"{p}: {key} must be a finite number, got {v!r}")
        return float(v)

    def whole(key: str) -> int | None:
        if key not in fields:
            return None
        v = fields[key]
        if _INTEGER_RE.fullmatch(v) is not None and len(v.lstrip("0")) > _MAX_DIGITS:
            # int() refuses more than 4300 digits with a message naming neither file nor key
            raise ValueError(f"{p}: {key} must be a whole number > 0, got {len(v)} digits")
        if _INTEGER_RE.fullmatch(v) is None or int(v) <= 0:
            raise ValueError(f"{p}: {key} must be a whole number > 0, got {_shown(v)}")
        return int(v)

    if ("width" in fields) != ("height" in fields):
        # One without the other (a misspelt "heigth") was dropped without a word: the file's
        # stated size went unchecked, and images of another resolution were given its focal
        # length and doffs. The OpenCV reader's rule for image_width and image_height.
        given, missing = ("width", "height") if "width" in fields else ("height", "width")
        raise ValueError(
            f"{p}: width and height go together, got {given}={fields[given]!r} and no {missing}"
        )
    cam0 = _matrix(fields["cam0"], "cam0", p)
    baseline = number("baseline")
    if not baseline > 0:
        raise ValueError(f"{p}: baseline must be > 0 mm, got {fields['baseline']!r}")
    # doffs is cx1 - cx0 by the format's definition: the two must agree, and either one gives
    # the other (a rig read as cam0, cam1 and one read as f, baseline, doffs are the same).
    if "cam1" in fields:
        cam1 = _matrix(fields["cam1"], "cam1", p)
        # The rectified views share f and cy (the format's [f 0 cx; 0 f cy; 0 0 1], rows
        # aligned), as read_kitti_calib requires of its pairs: a cam1 that differs was ignored,
        # and its pair matched and converted to depth as if it were rectified.
        for name, i, j in (("focal length fx", 0, 0), ("focal length fy", 1, 1), ("cy", 1, 2)):
            a, b = float(cam0[i, j]), float(cam1[i, j])
            if _differ(a, b):
                raise ValueError(
                    f"{p}: cam0 and cam1 are not a rectified pair: their {name} differ "
                    f"({a:g} and {b:g})"
                )
        cx_diff = float(cam1[0, 2] - cam0[0, 2])
        doffs = number("doffs") if "doffs" in fields else cx_diff
        if abs(doffs - cx_diff) > DOFFS_TOLERANCE_PX:
            raise ValueError(
                f"{p}: doffs must be cam1's cx - cam0's cx ({cam1[0, 2]:g} - {cam0[0, 2]:g} = "
                f"{cx_diff:g} px), got {fields['doffs']!r}"
            )
    else:
        doffs = number("doffs") if "doffs" in fields else 0.0
        cam1 = cam0.copy()
        cam1[0, 2] += doffs
    return MiddleburyCalib(
        cam0=cam0,
        cam1=cam1,
        doffs_px=doffs,
        baseline_mm=baseline,
        width_px=whole("width"),
        height_px=whole("height"),
        ndisp=whole("ndisp"),
    )


def read_middlebury_stereo_calibration(
    path: str | os.PathLike[str], *, image_size: tuple[int, int] | None = None
) -> StereoCalibration:
    """A Middlebury ``calib.txt`` (see :func:`read_middlebury_calib`) as a rectified
    :class:`StereoCalibration`: K1 = cam0, K2 = cam1, no distortion, R = I,
    T = (-baseline, 0, 0) in metres, image size from ``width`` and ``height`` (or
    ``image_size=``), R1, R2, P1, P2, Q as ``cv2.stereoRectify`` lays them out (Q keeps
    doffs). Raises as :func:`read_middlebury_calib`, and ValueError when the image size is
    missing or disagrees with ``image_size=``."""
    p = _path(path)
    c = read_middlebury_calib(p)
    found = (c.width_px, c.height_px) if c.width_px and c.height_px else None
    size = _image_size_of(found, image_size, str(p), "width, height")
    return _rectified_calibration(c.cam0, c.cam1, c.baseline_mm / 1000.0, size, str(p))
