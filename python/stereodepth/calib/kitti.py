"""KITTI calibration files: ``P0:`` .. ``P3:`` lines of KITTI 2012/2015's ``calib/*.txt``, or
``P_rect_0i:`` of ``calib_cam_to_cam.txt``.

The format is one ``NAME: values`` a line; other names (``calib_time``, ``Tr``, ``R_rect_00``,
...) are skipped. LF, CR LF or CR line ends, blank lines and surrounding spaces are accepted.
The format has no comments, so any other line is refused, as are a name given twice, a camera
given under both its names (``P2`` and ``P_rect_02``), a matrix that is not 12 finite numbers,
and two cameras that are not a rectified pair.

Source: A. Geiger et al., "Vision meets Robotics: The KITTI Dataset", IJRR 2013 (the devkit's
readme for the file layout and the baseline ``B = (P_l[0, 3] - P_r[0, 3]) / fx``).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ._common import (
    _check_cameras,
    _check_image_size,
    _differ,
    _image_size_of,
    _path,
    _read_text,
)
from .stereo import Calibration, StereoCalibration, _rectified_calibration

__all__ = ["read_kitti_calib", "read_kitti_stereo_calibration"]

_FIELD_RE = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)")


def _fields(p: Path) -> dict[str, tuple[int, str]]:
    """Every ``NAME: values`` line of the file: {name: (line number, values)}."""
    fields: dict[str, tuple[int, str]] = {}
    for lineno, raw in enumerate(_read_text(p, "KITTI calibration file").splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        m = _FIELD_RE.fullmatch(line)
        if m is None:
            raise ValueError(f"{p}:{lineno}: expected 'NAME: values', got {line!r}")
        key, values = m.groups()
        if key in fields:
            raise ValueError(f"{p}:{lineno}: {key} is given twice (first on line {fields[key][0]})")
        fields[key] = (lineno, values)
    return fields


def _numbers(p: Path, fields: dict[str, tuple[int, str]], key: str, count: int) -> np.ndarray:
    lineno, text = fields[key]
    words = text.split()
    try:
        values = np.array([float(w) for w in words], dtype=np.float64)
    except ValueError:
        raise ValueError(f"{p}:{lineno}: {key} must be {count} numbers, got {text!r}") from None
    if len(words) != count:
        raise ValueError(f"{p}:{lineno}: {key} must be {count} numbers, got {len(words)}")
    if not np.isfinite(values).all():
        raise ValueError(f"{p}:{lineno}: {key} must be {count} finite numbers, got {text!r}")
    return values


def _projection(p: Path, fields: dict[str, tuple[int, str]], camera: int) -> tuple[str, np.ndarray]:
    """Camera ``camera``'s 3x4 projection matrix, under the name the file gives it."""
    keys = [k for k in (f"P{camera}", f"P_rect_0{camera}") if k in fields]
    if not keys:
        raise ValueError(f"{p}: missing P{camera} (or P_rect_0{camera}) in the KITTI calibration")
    if len(keys) > 1:
        raise ValueError(
            f"{p}:{fields[keys[1]][0]}: {keys[1]} gives camera {camera} again (first as "
            f"{keys[0]} on line {fields[keys[0]][0]})"
        )
    return keys[0], _numbers(p, fields, keys[0], 12).reshape(3, 4)


def _rectified_pair(
    p: Path, fields: dict[str, tuple[int, str]], left: int, right: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """The two cameras' projections, checked to be a rectified pair, and the baseline in m."""
    (kl, pl), (kr, pr) = _projection(p, fields, left), _projection(p, fields, right)
    f = float(pl[0, 0])
    if not f > 0:
        raise ValueError(f"{p}: {kl} focal length must be > 0, got {f}")
    for name, a, b in (
        ("focal length fx", pl[0, 0], pr[0, 0]),
        ("focal length fy", pl[1, 1], pr[1, 1]),
        ("principal point row cy", pl[1, 2], pr[1, 2]),
    ):
        if _differ(a, b):
            raise ValueError(
                f"{p}: {kl} and {kr} are not a rectified pair: their {name} differ ({a} and {b})"
            )
    for key, m in ((kl, pl), (kr, pr)):
        if m[0, 1] != 0 or m[1, 0] != 0 or not np.array_equal(m[2, :3], [0, 0, 1]):
            raise ValueError(
                f"{p}: {key} must be a rectified projection [fx 0 cx tx; 0 fy cy ty; 0 0 1 tz], "
                f"got {m.tolist()}"
            )
    baseline = float(pl[0, 3] - pr[0, 3]) / f
    if not baseline > 0:
        raise ValueError(
            f"{p}: camera {right} must be right of camera {left}, got a baseline of {baseline} m"
        )
    return pl, pr, baseline


def read_kitti_calib(path: str | os.PathLike[str], cams: tuple[int, int] = (2, 3)) -> Calibration:
    """The rig of two rectified KITTI cameras (default 2 and 3, the colour pair): the left
    camera's focal length and principal point in pixels, the baseline in metres from the two
    projection matrices, and doffs = cx_r - cx_l; ``image_size`` is the left camera's
    ``S_rect_0i`` (calib_cam_to_cam.txt's rectified size; None in files without it, such as
    KITTI 2012's), so that images of another size are refused rather than given depths off by
    the scale factor.

    Raises FileNotFoundError, and ValueError naming the file, the line and what was wrong
    (see the module's documentation for the rules); ``cams`` must be two different integers
    >= 0 (TypeError or ValueError naming ``cams`` otherwise)."""
    p = _path(path)
    # Checked as read_kitti_stereo_calibration's cameras: (2,) was Python's "not enough
    # values to unpack", (2.0, 3) and (-1, 3) looked for keys P2.0 and P-1 in the file.
    lc, rc = _check_cameras(cams, "cams", "KITTI ")
    fields = _fields(p)
    pl, pr, baseline = _rectified_pair(p, fields, lc, rc)
    return Calibration(
        focal_px=float(pl[0, 0]),
        baseline_m=baseline,
        doffs_px=float(pr[0, 2] - pl[0, 2]),
        cx_px=float(pl[0, 2]),
        cy_px=float(pl[1, 2]),
        source=str(p),
        image_size=_rectified_size(p, fields, lc),
    )


def _rectified_size(
    p: Path, fields: dict[str, tuple[int, str]], camera: int
) -> tuple[int, int] | None:
    """``S_rect_0{camera}`` (calib_cam_to_cam.txt's rectified image size), None if absent."""
    key = f"S_rect_0{camera}"
    if key not in fields:
        return None
    return _check_image_size(_numbers(p, fields, key, 2).tolist(), str(p), key)


def read_kitti_stereo_calibration(
    path: str | os.PathLike[str],
    *,
    cameras: tuple[int, int] = (2, 3),
    image_size: tuple[int, int] | None = None,
) -> StereoCalibration:
    """A KITTI calibration file as a rectified :class:`StereoCalibration` of two of its
    cameras (default 2 and 3, the colour pair). ``calib_cam_to_cam.txt``'s ``S_rect_0i`` gives
    the image size; KITTI 2012's files have none, so pass ``image_size=(width, height)``.

    K_i is P_i's left 3x3, no distortion, R = I, and T = (-B, 0, 0) with the baseline in
    metres as KITTI's development kit computes it (the sub-millimetre y and z offsets in the
    projections are dropped); R1, R2, P1, P2, Q as ``cv2.stereoRectify`` lays them out,
    relative to the left camera.

    Raises FileNotFoundError, and ValueError naming the file, the line and the key (see the
    module's documentation for the rules), and for an image size that is missing or
    disagrees with ``image_size=``; TypeError for ``cameras`` that are not integers."""
    first, second = _check_cameras(cameras)
    p = _path(path)
    fields = _fields(p)
    pl, pr, baseline = _rectified_pair(p, fields, first, second)
    found = _rectified_size(p, fields, first)
    size = _image_size_of(found, image_size, str(p), f"S_rect_0{first}")
    return _rectified_calibration(pl[:, :3].copy(), pr[:, :3].copy(), baseline, size, str(p))
