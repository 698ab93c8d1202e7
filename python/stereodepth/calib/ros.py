"""A pair of ROS ``camera_info`` YAML files (sensor_msgs/CameraInfo: camera_matrix,
distortion_model, distortion_coefficients, rectification_matrix, projection_matrix)."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ._common import (
    _check_distortion,
    _check_implicit_baseline,
    _check_intrinsics,
    _check_model,
    _check_rotation,
    _fail,
    _image_size_of,
    _path,
    _read_text,
    _shown,
    _unit,
)
from ._trees import _file_image_size, _lookup, _numbers, _ros_matrix, _yaml_tree
from .stereo import StereoCalibration

__all__ = ["read_ros_stereo_calibration"]


#: camera_calibration_parsers' keys and the CameraInfo message's (ROS 1, ROS 2), with shapes.
_MESSAGE_KEYS = {
    "camera_matrix": ("K", "k", (3, 3)),
    "distortion_coefficients": ("D", "d", (-1,)),
    "rectification_matrix": ("R", "r", (3, 3)),
    "projection_matrix": ("P", "p", (3, 4)),
}


def _is_camera_info_message(tree: dict[str, Any]) -> bool:
    """A CameraInfo message as ``rostopic echo`` (K, D, R, P) or ``ros2 topic echo`` (k, d,
    r, p) prints it: flat lists, ``width`` and ``height``, ``distortion_model``."""
    return all(upper in tree or lower in tree for upper, lower, _ in _MESSAGE_KEYS.values()) and (
        "distortion_model" in tree
    )


def _message_matrices(tree: dict[str, Any], where: str) -> tuple[dict[str, Any], dict[str, str]]:
    """A CameraInfo message's matrices as arrays under its own keys, and the key of each of
    camera_calibration_parsers' names. Binning and a region of interest are refused: the
    calibration is then of other pixels than the message's images."""
    out: dict[str, Any] = {}
    names: dict[str, str] = {}
    for field, (upper, lower, shape) in _MESSAGE_KEYS.items():
        hit = _lookup(tree, (upper, lower), where)
        if hit is None:
            raise _fail(where, f"missing key {upper} (or {lower})")
        key, value = hit
        values = _numbers(value, where, key)
        count = math.prod(shape)
        if shape != (-1,) and len(values) != count:
            raise _fail(where, f"{key} must be {count} numbers (row by row), got {len(values)}")
        out[key] = np.array(values, dtype=np.float64).reshape(shape)
        names[field] = key
    for key in ("binning_x", "binning_y"):
        v = tree.get(key, 0)
        if v not in (0, 1):
            raise _fail(where, f"{key} is {_shown(v)}: binned camera_info is not read (0 or 1)")
    roi = tree.get("roi")
    if isinstance(roi, dict) and any(
        roi.get(k, 0) not in (0, None) for k in ("x_offset", "y_offset", "height", "width")
    ):
        raise _fail(where, f"roi is {_shown(roi)}: a camera_info of a region is not read")
    return out, names


def _ros_camera(p: Path, scale: float) -> dict[str, Any]:
    where = str(p)
    tree = _yaml_tree(p, _read_text(p, "ROS camera_info file"))
    if "camera_matrix" not in tree and _is_camera_info_message(tree):
        matrices, names = _message_matrices(tree, where)
        tree = {**tree, **matrices}
    else:
        names = {field: field for field in _MESSAGE_KEYS}
    key = names["camera_matrix"]
    k = _check_intrinsics(_ros_matrix(tree, key, where, (3, 3)), where, key)
    if "distortion_model" not in tree:
        raise _fail(where, "missing key distortion_model")
    model = _check_model(tree["distortion_model"], where, "distortion_model")
    key = names["distortion_coefficients"]
    d = _ros_matrix(tree, key, where, (-1,))
    d = _check_distortion(d, model, where, key, named=tree["distortion_model"])
    key = names["rectification_matrix"]
    r = _check_rotation(_ros_matrix(tree, key, where, (3, 3)), where, key)
    key = names["projection_matrix"]
    pm = _ros_matrix(tree, key, where, (3, 4))
    kp = _check_intrinsics(pm[:, :3], where, f"{key}[:, :3]")
    pm[:, 3] *= scale
    return {
        "where": where,
        "K": k,
        "model": model,
        "D": d,
        "R": r,
        "P": pm,
        "t": np.linalg.solve(kp, pm[:, 3]),  # the rectified camera's offset, metres
        "size": _file_image_size(tree, where),
    }


def read_ros_stereo_calibration(
    left_path: str | os.PathLike[str],
    right_path: str | os.PathLike[str],
    *,
    translation_unit: str | None = None,
    image_size: tuple[int, int] | None = None,
) -> StereoCalibration:
    """A stereo calibration from the two ROS camera_info YAML files of a rectified pair, as
    ROS's camera_calibration writes them (wiki.ros.org/camera_calibration_parsers,
    sensor_msgs/CameraInfo): ``image_width``, ``image_height``, ``camera_matrix``,
    ``distortion_model`` (``plumb_bob``, ``rational_polynomial``, ``equidistant``),
    ``distortion_coefficients``, ``rectification_matrix`` and ``projection_matrix``, each
    matrix as ``{rows, cols, data}``. A CameraInfo message saved with ``rostopic echo -n1``
    (``K``, ``D``, ``R``, ``P`` as flat lists row by row, ``width``, ``height``) or ``ros2
    topic echo --once`` (``k``, ``d``, ``r``, ``p``), its closing ``---`` included, is read
    too; one with ``binning_x``/``binning_y`` over 1 or a non-empty ``roi`` is refused (its
    calibration is of other pixels than its images).

    ROS stores no R and T: they are recovered from the rectification. Each rectified camera
    i has ``P_i = K'_i [I | t_i]`` (for the right camera of a horizontal pair ``Tx = -fx' B``,
    so t = (-B, 0, 0)); a point X of the left camera is ``R1 X - t_1`` in the common
    rectified frame, so ``R = R2^T R1`` and ``T = R2^T (t_2 - t_1)``. The two projections
    must share fx' and fy' (a rectified pair). B is in metres by ROS's convention;
    ``translation_unit`` says otherwise; without it (None) a baseline over
    ``MAX_IMPLICIT_BASELINE_M`` (10 m) is refused, as for OpenCV files: far more likely a
    target measured in mm (every depth 1000 times too large); pass ``"m"`` to accept it.
    R1, R2, P1, P2 are the files' rectification and projection matrices.

    Raises FileNotFoundError, ImportError without PyYAML, and ValueError naming the file
    and the key for a missing key, a wrong shape, a non-finite value, a rectification matrix
    that is not a rotation, a distortion count that does not fit the model, cameras with
    different distortion models, image sizes or rectified focal lengths, a right camera
    with no offset or files given in the wrong order, or a baseline over 10 m read without
    a translation unit."""
    scale = _unit(translation_unit)
    left = _ros_camera(_path(left_path, "left_path"), scale)
    right = _ros_camera(_path(right_path, "right_path"), scale)
    where = f"{left['where']} + {right['where']}"
    if left["model"] != right["model"]:
        raise _fail(where, f"distortion_model differs: {left['model']!r} and {right['model']!r}")
    sizes = {s for s in (left["size"], right["size"]) if s is not None}
    if len(sizes) > 1:
        raise _fail(where, f"image_width/image_height differ: {left['size']} and {right['size']}")
    size = _image_size_of(
        sizes.pop() if sizes else None, image_size, where, "image_width, image_height"
    )
    pl, pr = left["P"], right["P"]
    if not np.allclose(pl[:2, :2], pr[:2, :2], rtol=1e-9, atol=0):
        raise _fail(
            where,
            "projection_matrix fx and fy differ between the cameras, got "
            f"{pl[0, 0]}, {pl[1, 1]} and {pr[0, 0]}, {pr[1, 1]}: not a rectified pair",
        )
    if not np.any(right["t"]):
        side = "left" if np.any(left["t"]) else "right"
        raise _fail(
            right["where"],
            "projection_matrix has no translation (Tx = Ty = 0): not the right camera of a "
            "stereo calibration" + (" (are the files swapped?)" if side == "left" else ""),
        )
    if pr[0, 3] - pl[0, 3] > 0:
        raise _fail(
            right["where"],
            f"projection_matrix Tx = {pr[0, 3]} > 0: this camera is left of the other "
            "(ROS gives the right camera Tx = -fx * baseline < 0): are the files swapped, or "
            "Tx's sign wrong?",
        )
    _check_implicit_baseline(
        float(np.linalg.norm(right["t"] - left["t"])),
        translation_unit,
        right["where"],
        "projection_matrix",
        "ROS's convention",
    )
    r = right["R"].T @ left["R"]
    t = right["R"].T @ (right["t"] - left["t"])
    return StereoCalibration(
        K1=left["K"],
        D1=left["D"],
        K2=right["K"],
        D2=right["D"],
        distortion_model=left["model"],
        R=r,
        T=t,
        image_size=size,
        R1=left["R"],
        R2=right["R"],
        P1=pl,
        P2=pr,
        source=where,
    )
