"""Calibration files, every format in one place.

Rectified rigs: Middlebury's ``calib.txt`` (:func:`read_middlebury_calib`) and KITTI's calibration
files (:func:`read_kitti_calib`), read into the rig a matcher's disparity turns into depth
(:class:`Calibration`; :func:`read_calibration` tells the two apart).

Raw or rectified stereo calibrations, into one :class:`StereoCalibration` in OpenCV's conventions
(:func:`read_stereo_calibration` tells the format from the content): OpenCV FileStorage YAML and
XML, a pair of ROS camera_info files, Kalibr camchains, Middlebury and KITTI. YAML files need
PyYAML, the ``calib`` extra: ``pip install "stereodepth[calib]"``.
"""

from __future__ import annotations

from ._common import DISTORTION_COUNTS, TRANSLATION_UNITS
from .detect import read_calibration, read_stereo_calibration, rectified_format
from .kalibr import read_kalibr_stereo_calibration
from .kitti import read_kitti_calib, read_kitti_stereo_calibration
from .middlebury import MiddleburyCalib, read_middlebury_calib, read_middlebury_stereo_calibration
from .opencv import read_opencv_stereo_calibration
from .ros import read_ros_stereo_calibration
from .stereo import Calibration, StereoCalibration

__all__ = [
    "DISTORTION_COUNTS",
    "TRANSLATION_UNITS",
    "Calibration",
    "MiddleburyCalib",
    "StereoCalibration",
    "read_calibration",
    "read_kalibr_stereo_calibration",
    "read_kitti_calib",
    "read_kitti_stereo_calibration",
    "read_middlebury_calib",
    "read_middlebury_stereo_calibration",
    "read_opencv_stereo_calibration",
    "read_ros_stereo_calibration",
    "read_stereo_calibration",
    "rectified_format",
]
