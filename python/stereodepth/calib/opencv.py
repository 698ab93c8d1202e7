"""OpenCV FileStorage stereo calibrations: YAML and XML as written by the users of
``cv2.stereoCalibrate`` (M1/K1, D1, M2/K2, D2, R, T and optionally R1, R2, P1, P2, Q)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ._common import (
    MAX_IMPLICIT_BASELINE_M,
    _check_array,
    _check_distortion,
    _check_intrinsics,
    _check_model,
    _check_rotation,
    _fail,
    _image_size_of,
    _opencv_rational,
    _path,
    _shown,
    _unit,
)
from ._trees import _file_image_size, _lookup, _read_tree, _require
from .stereo import StereoCalibration

__all__ = ["read_opencv_stereo_calibration"]


_OPENCV_NAMES: dict[str, tuple[str, ...]] = {
    "K1": ("K1", "M1", "cameraMatrix1"),
    "D1": ("D1", "distCoeffs1"),
    "K2": ("K2", "M2", "cameraMatrix2"),
    "D2": ("D2", "distCoeffs2"),
    "R": ("R",),
    "T": ("T",),
    "R1": ("R1",),
    "R2": ("R2",),
    "P1": ("P1",),
    "P2": ("P2",),
    "Q": ("Q",),
}


#: The matrices each file of a split calibration must hold at least one of.
_MATRIX_KEYS = frozenset(n for names in _OPENCV_NAMES.values() for n in names)


def read_opencv_stereo_calibration(
    path: str | os.PathLike[str],
    extrinsics_path: str | os.PathLike[str] | None = None,
    *,
    translation_unit: str | None = None,
    image_size: tuple[int, int] | None = None,
    distortion_model: str | None = None,
) -> StereoCalibration:
    """A stereo calibration saved with ``cv2.FileStorage`` (YAML, XML or JSON) after
    ``cv2.stereoCalibrate`` (and ``cv2.stereoRectify``), as OpenCV's stereo_calib sample and
    most scripts write it: ``M1``/``K1``/``cameraMatrix1``, ``D1``/``distCoeffs1``, the same
    for camera 2, ``R``, ``T``, and optionally ``R1``, ``R2``, ``P1``, ``P2``, ``Q``, the image
    size (``image_size``/``imageSize`` as (width, height), or ``image_width`` and
    ``image_height``) and ``distortion_model``. OpenCV's stereo_calib sample writes two files,
    intrinsics.yml and extrinsics.yml: pass the second as ``extrinsics_path`` (a key in both
    is refused, and so is a file with none of these matrices).

    YAML needs PyYAML (``pip install "stereodepth[calib]"``); OpenCV's ``%YAML:1.0``
    directive and ``!!opencv-matrix`` tags are understood. FileStorage's JSON (its matrices
    objects with ``"type_id": "opencv-matrix"``) is read as YAML, of which it is a subset. XML
    is read with ``xml.etree`` (files with a DOCTYPE are refused).

    Units: OpenCV's T (and P2's last column, Q's last row) is in the unit of the
    calibration target's square size, which the file does not record: ``translation_unit``
    says which it is (``"m"``, ``"cm"``, ``"mm"``, ``"um"``, ``"in"``, ``"ft"``) and T is
    converted to metres. Without it (None) T is read as metres, but a T longer than
    ``MAX_IMPLICIT_BASELINE_M`` (10 m) is refused: it is far more likely millimetres read as
    metres (every depth 1000 times too large) than a 10 m rig; pass ``"m"`` to accept it.
    Distortion: 5 or 8 coefficients are the plumb_bob (radtan) model unless the file's
    ``distortion_model`` or ``distortion_model=`` says ``"equidistant"``; 4 coefficients need
    one of them to say which (``"equidistant"`` for ``cv2.fisheye`` calibrations, ``"plumb_bob"``
    for k1 k2 p1 p2): read as either, the other would be rectified wrongly without a word.
    OpenCV's 12 and 14 coefficient forms are accepted when the thin prism and tilt terms are 0.

    Raises FileNotFoundError for a missing file, ImportError without PyYAML, ValueError
    naming the file and the key for a missing key, a wrong shape, a non-finite value, a
    rotation that is not one, a distortion count that does not fit the model, 4 coefficients
    without a model, or an image
    size that is missing (pass ``image_size=``) or disagrees with ``image_size=``."""
    scale = _unit(translation_unit)
    paths = [_path(path)] + (
        [_path(extrinsics_path, "extrinsics_path")] if extrinsics_path is not None else []
    )
    tree: dict[str, Any] = {}
    origin: dict[str, str] = {}
    for p in paths:
        _, t = _read_tree(p, "OpenCV calibration file")
        if len(paths) > 1 and not any(k in _MATRIX_KEYS for k in t):
            raise _fail(
                f"{p}",
                "none of the matrices of an OpenCV stereo calibration (M1/K1, D1, M2/K2, D2, "
                "R, T, R1, R2, P1, P2, Q): not a part of a split calibration "
                f"(its keys: {_shown(sorted(map(str, t)))})",
            )
        for key, value in t.items():
            if key in tree:
                raise _fail(f"{p}", f"{key} is also given in {origin[key]}")
            tree[key], origin[key] = value, str(p)
    where_all = " + ".join(str(p) for p in paths)

    def get(field: str, required: bool = True) -> tuple[str, Any, str] | None:
        hit = (_require if required else _lookup)(tree, _OPENCV_NAMES[field], where_all)
        return None if hit is None else (hit[0], hit[1], origin[hit[0]])

    model = "plumb_bob"
    if "distortion_model" in tree:
        model = _check_model(
            tree["distortion_model"], origin["distortion_model"], "distortion_model"
        )
    if distortion_model is not None:
        given = _check_model(distortion_model, "distortion_model=", "distortion_model")
        if "distortion_model" in tree and given != model:
            raise _fail(
                origin["distortion_model"],
                f"distortion_model is {model!r}, distortion_model= says {given!r}",
            )
        model = given
    # Four coefficients are k1 k2 p1 p2 (plumb_bob) or k1 k2 k3 k4 (OpenCV's fisheye module,
    # whose calibrations give four and nothing else; cv2.stereoCalibrate gives 5 or more):
    # a file that does not say which is refused rather than read as either.
    told = "distortion_model" in tree or distortion_model is not None
    out: dict[str, Any] = {}
    for field in ("K1", "K2"):
        key, value, where = get(field)  # type: ignore[misc]
        out[field] = _check_intrinsics(value, where, key)
    for field in ("D1", "D2"):
        key, value, where = get(field)  # type: ignore[misc]
        d = _check_array(value, where, key, (-1,))
        if model == "plumb_bob":
            d = _opencv_rational(d, where, key)
        if d.size == 4 and not told:
            raise _fail(
                where,
                f"{key} has 4 coefficients, which both OpenCV's fisheye module (equidistant: "
                "k1 k2 k3 k4) and the plumb_bob model (k1 k2 p1 p2) write; say which with "
                "distortion_model= (or a distortion_model key in the file)",
            )
        out[field] = _check_distortion(d, model, where, key)
    key, value, where = get("R")  # type: ignore[misc]
    out["R"] = _check_rotation(value, where, key)
    key, value, where = get("T")  # type: ignore[misc]
    tvec = _check_array(value, where, key, (3,))
    length = float(np.linalg.norm(tvec))
    if translation_unit is None and length > MAX_IMPLICIT_BASELINE_M:
        raise _fail(
            where,
            f"{key} is {length:g} long: read as metres (no translation unit given) that is an "
            f"unlikely {length:g} m baseline. OpenCV's T is in the unit of the calibration "
            "target's squares: give its unit with translation_unit, e.g. 'mm', or 'm' to "
            "accept metres",
        )
    out["T"] = tvec * scale
    for field in ("R1", "R2", "P1", "P2", "Q"):
        hit = get(field, required=False)
        if hit is None:
            continue
        key, value, where = hit
        if field in ("R1", "R2"):
            out[field] = _check_rotation(value, where, key)
        elif field == "Q":
            q = _check_array(value, where, key, (4, 4))
            q[3] /= scale
            out[field] = q
        else:
            pm = _check_array(value, where, key, (3, 4))
            pm[:, 3] *= scale
            out[field] = pm
    found = _file_image_size(tree, where_all)
    size = _image_size_of(found, image_size, where_all, "image_size or image_width/height")
    return StereoCalibration(distortion_model=model, image_size=size, source=where_all, **out)
