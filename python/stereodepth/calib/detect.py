"""Any calibration file, its format told by its content."""

from __future__ import annotations

import os
import re
from typing import Any

from ._common import _check_cameras, _fail, _path, _read_text
from ._trees import _yaml_tree
from .kalibr import read_kalibr_stereo_calibration
from .kitti import read_kitti_calib, read_kitti_stereo_calibration
from .middlebury import read_middlebury_calib, read_middlebury_stereo_calibration
from .opencv import _OPENCV_NAMES, read_opencv_stereo_calibration
from .ros import _is_camera_info_message, read_ros_stereo_calibration
from .stereo import Calibration, StereoCalibration

__all__ = ["read_calibration", "read_stereo_calibration", "rectified_format"]

# The calibration files of already rectified pairs, told by their content.
_MIDDLEBURY_RE = re.compile(r"^[ \t]*cam0[ \t]*=", flags=re.MULTILINE)
_KITTI_RE = re.compile(r"^[ \t]*P(_rect_0)?\d[ \t]*:[ \t]*[-+.\d]", flags=re.MULTILINE)


_OPENCV_YAML_MATRIX_RE = re.compile(r"^[ \t]*[\w.-]+[ \t]*:[ \t]*!!opencv-", flags=re.MULTILINE)


def _is_opencv_storage(text: str) -> bool:
    """Whether ``text`` is a file cv2.FileStorage wrote: YAML (its ``%YAML`` directive, or a
    key whose value is tagged ``!!opencv-``), XML, or JSON with OpenCV's matrix objects."""
    head = text.lstrip("\ufeff \t\r\n")
    if re.match(r"%YAML[: ]?\d", head) or (head.startswith("<") and "<opencv_storage" in text):
        return True
    if _OPENCV_YAML_MATRIX_RE.search(text):
        return True
    return head.startswith("{") and '"type_id"' in text and "opencv-" in text


def _rectified_format_of(text: str) -> str | None:
    if _MIDDLEBURY_RE.search(text):
        return "middlebury"
    if _KITTI_RE.search(text):
        return "kitti"
    return None


def rectified_format(path: str | os.PathLike[str]) -> str | None:
    """``"middlebury"`` or ``"kitti"`` when ``path`` is a calibration file of an already
    rectified pair (a Middlebury ``calib.txt``, a KITTI calibration file), told by its content
    as :func:`read_stereo_calibration` tells it; None for any other file (a raw calibration,
    to be rectified). Raises FileNotFoundError, or ValueError for a file that is not text."""
    return _rectified_format_of(_read_text(_path(path), "calibration file"))


def read_stereo_calibration(
    path: str | os.PathLike[str],
    *,
    second_path: str | os.PathLike[str] | None = None,
    translation_unit: str | None = None,
    image_size: tuple[int, int] | None = None,
    distortion_model: str | None = None,
    cameras: tuple[int, int] | None = None,
) -> StereoCalibration:
    """A stereo calibration from any file this module reads, the format told by content:

    - OpenCV FileStorage XML (``<opencv_storage>``), YAML or JSON (keys such as M1, K1, R, T):
      :func:`read_opencv_stereo_calibration`, ``second_path`` the second file when the
      calibration is split in two (intrinsics and extrinsics);
    - ROS camera_info YAML (``camera_matrix``, or a CameraInfo message as ``rostopic echo``
      or ``ros2 topic echo`` prints it): :func:`read_ros_stereo_calibration`, the left
      camera's file, ``second_path`` the right camera's (required);
    - Kalibr camchain YAML (``cam0`` with ``intrinsics``):
      :func:`read_kalibr_stereo_calibration`;
    - Middlebury ``calib.txt`` (``cam0=[...]``): :func:`read_middlebury_stereo_calibration`;
    - KITTI (``P2: ...`` or ``P_rect_02: ...`` lines): :func:`read_kitti_stereo_calibration`.

    The keywords go to the readers that take them: ``translation_unit`` (OpenCV, ROS,
    Kalibr; None for metres, with a plausibility check: a baseline over 10 m is refused;
    Middlebury and KITTI files state their unit, so only None or "m" is accepted there),
    ``image_size`` (all), ``distortion_model`` (OpenCV), ``cameras`` (Kalibr, default (0, 1);
    KITTI, default (2, 3)). Raises FileNotFoundError, ValueError naming the file for an
    unknown format, a file over 4 MiB (``MAX_FILE_BYTES``: calibration files are a few kB),
    a keyword that does not apply or any fault the reader finds, and
    ImportError when a YAML file needs PyYAML."""
    p = _path(path)
    if second_path is not None:
        second_path = _path(second_path, "second_path")
    text = _read_text(p, "calibration file")
    head = text.lstrip()

    def refuse(kind: str, **given: Any) -> None:
        for name, value in given.items():
            if value:
                raise _fail(str(p), f"{name} does not apply to a {kind} file")

    def opencv() -> StereoCalibration:
        refuse("OpenCV", cameras=cameras)
        return read_opencv_stereo_calibration(
            p,
            second_path,
            translation_unit=translation_unit,
            image_size=image_size,
            distortion_model=distortion_model,
        )

    if head.startswith(("<?xml", "<opencv_storage")):
        return opencv()
    rectified = _rectified_format_of(text)
    if rectified == "middlebury":
        refuse(
            "Middlebury",
            second_path=second_path,
            distortion_model=distortion_model,
            cameras=cameras,
            translation_unit=translation_unit not in (None, "m"),
        )
        return read_middlebury_stereo_calibration(p, image_size=image_size)
    if rectified == "kitti":
        refuse(
            "KITTI",
            second_path=second_path,
            distortion_model=distortion_model,
            translation_unit=translation_unit not in (None, "m"),
        )
        return read_kitti_stereo_calibration(p, cameras=cameras or (2, 3), image_size=image_size)
    known = (
        "not a calibration file this reader knows (OpenCV FileStorage, ROS camera_info, Kalibr "
        "camchain, Middlebury calib.txt, KITTI)"
    )
    try:
        tree = _yaml_tree(p, text)
    except ValueError as exc:
        if head.startswith("%YAML") or "!!opencv-" in text:
            raise  # an OpenCV file with a fault: say which
        raise _fail(str(p), f"{known}; as YAML: {str(exc)[len(str(p)) + 2 :]}") from exc
    if "camera_matrix" in tree or _is_camera_info_message(tree):
        refuse("ROS camera_info", distortion_model=distortion_model, cameras=cameras)
        if second_path is None:
            raise _fail(
                str(p),
                "a ROS camera_info file holds one camera: pass the right camera's file "
                "as second_path",
            )
        return read_ros_stereo_calibration(
            p, second_path, translation_unit=translation_unit, image_size=image_size
        )
    if isinstance(tree.get("cam0"), dict) and "intrinsics" in tree["cam0"]:
        refuse("Kalibr", second_path=second_path, distortion_model=distortion_model)
        return read_kalibr_stereo_calibration(
            p, cameras=cameras or (0, 1), translation_unit=translation_unit, image_size=image_size
        )
    if any(n in tree for names in _OPENCV_NAMES.values() for n in names):
        return opencv()
    raise _fail(str(p), known)


def read_calibration(
    path: str | os.PathLike[str], cams: tuple[int, int] | None = None
) -> Calibration:
    """A Middlebury ``calib.txt`` or a KITTI calibration file, told apart by their content.
    A Middlebury file's ``width`` and ``height`` are the result's ``image_size``.

    ``cams`` are the KITTI cameras (default 2 and 3); a Middlebury file has one pair and
    does not use them, but they are checked as :func:`read_kitti_calib` checks them
    (TypeError or ValueError naming ``cams``). Raises FileNotFoundError, IsADirectoryError,
    and ValueError naming the file for a file that is not text or is larger than
    ``MAX_FILE_BYTES`` (4 MiB; calibration files are a few kB), before reading it whole, for
    an OpenCV FileStorage file (:func:`read_stereo_calibration` reads those), and every error
    of the reader."""
    p = _path(path)
    if cams is not None:
        # A Middlebury file ignored them: cams="x" or (2.0, 3) went through without a word.
        cams = _check_cameras(cams, "cams", "KITTI ")
    # Size-checked: read whole first, a multi-gigabyte file given by mistake was decoded
    # into memory before the readers refused it.
    text = _read_text(p, "calibration file")
    if _rectified_format_of(text) == "kitti":
        return read_kitti_calib(p, cams or (2, 3))
    if _is_opencv_storage(text):
        # Its P1: and P2: lines were read as KITTI's ("expected 'NAME: values', got '%YAML
        # 1.2'"), a file without them as a Middlebury calib.txt.
        raise _fail(
            str(p),
            "an OpenCV FileStorage file, not the calibration of a rectified pair that "
            "read_calibration reads (a Middlebury calib.txt, a KITTI calibration file): read "
            "an OpenCV stereo calibration (M1, D1, M2, D2, R, T) with read_stereo_calibration "
            "and rectify the pair with it",
        )
    # A P line without numbers: a faulty KITTI file, whose reader says what is wrong.
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
        image_size=None if c.width_px is None or c.height_px is None else (c.width_px, c.height_px),
    )
