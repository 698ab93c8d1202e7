"""Kalibr camchain YAML files (pinhole cameras with radtan or equidistant distortion, T_cn_cnm1)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ._common import (
    _check_array,
    _check_cameras,
    _check_distortion,
    _check_image_size,
    _check_implicit_baseline,
    _check_intrinsics,
    _check_model,
    _check_rotation,
    _fail,
    _image_size_of,
    _path,
    _read_text,
    _unit,
)
from ._trees import _numbers, _yaml_tree
from .stereo import StereoCalibration

__all__ = ["read_kalibr_stereo_calibration"]


def read_kalibr_stereo_calibration(
    path: str | os.PathLike[str],
    *,
    cameras: tuple[int, int] = (0, 1),
    translation_unit: str | None = None,
    image_size: tuple[int, int] | None = None,
) -> StereoCalibration:
    """A stereo calibration from a Kalibr camchain YAML (``kalibr_calibrate_cameras``'s
    ``camchain-*.yaml``, github.com/ethz-asl/kalibr/wiki/yaml-formats): for each ``camN``,
    ``camera_model`` (``pinhole``; omni, ds, eucm are not read), ``intrinsics``
    ``[fu, fv, pu, pv]``, ``distortion_model`` (``radtan``: k1 k2 r1 r2, OpenCV's plumb_bob
    with 4 coefficients; ``equidistant``: k1..k4; ``none``), ``distortion_coeffs``,
    ``resolution`` ``[width, height]``, and for every camera after the first
    ``T_cn_cnm1``, the 4x4 transform from camera n-1 to camera n (metres).

    ``cameras`` picks the pair, left first (default ``cam0``, ``cam1``); transforms along
    the chain are composed. ``translation_unit`` is "m" by Kalibr's convention; without it
    (None) a baseline over ``MAX_IMPLICIT_BASELINE_M`` (10 m) is refused, as for OpenCV
    files: far more likely a target measured in mm; pass ``"m"`` to accept it.

    Raises FileNotFoundError, ImportError without PyYAML, and ValueError naming the file
    and the key (``cam1.T_cn_cnm1``) for a missing key, a wrong shape, a non-finite value, a
    transform whose rotation is not one or whose last row is not 0 0 0 1, an unsupported
    camera model, a distortion count that does not fit the model, and cameras with
    different distortion models or resolutions, or a baseline over 10 m read without a
    translation unit; TypeError for ``cameras`` that are not
    integers."""
    scale = _unit(translation_unit)
    first, second = _check_cameras(cameras)
    p = _path(path)
    where = str(p)
    tree = _yaml_tree(p, _read_text(p, "Kalibr camchain"))

    def cam(n: int) -> dict[str, Any]:
        node = tree.get(f"cam{n}")
        if not isinstance(node, dict):
            raise _fail(
                where, f"missing key cam{n}" if node is None else f"cam{n} must be a mapping"
            )
        return node

    def field(n: int, key: str) -> Any:
        node = cam(n)
        if key not in node:
            raise _fail(where, f"missing key cam{n}.{key}")
        return node[key]

    intr: dict[int, dict[str, Any]] = {}
    for n in (first, second):
        model_name = field(n, "camera_model")
        if model_name != "pinhole":
            raise _fail(
                where,
                f"cam{n}.camera_model must be 'pinhole', got {model_name!r} (omni, ds "
                "and eucm cameras are not read)",
            )
        fu, fv, pu, pv = _check_array(
            _numbers(field(n, "intrinsics"), where, f"cam{n}.intrinsics"),
            where,
            f"cam{n}.intrinsics",
            (4,),
        )
        k = _check_intrinsics([[fu, 0, pu], [0, fv, pv], [0, 0, 1]], where, f"cam{n}.intrinsics")
        model = _check_model(field(n, "distortion_model"), where, f"cam{n}.distortion_model")
        coeffs = _numbers(field(n, "distortion_coeffs"), where, f"cam{n}.distortion_coeffs")
        d = _check_distortion(
            coeffs, model, where, f"cam{n}.distortion_coeffs", named=field(n, "distortion_model")
        )
        size = _check_image_size(field(n, "resolution"), where, f"cam{n}.resolution")
        intr[n] = {"K": k, "D": d, "model": model, "size": size}
    a, b = intr[first], intr[second]
    if a["model"] != b["model"]:
        raise _fail(
            where,
            f"cam{first} and cam{second} have different distortion models: "
            f"{a['model']!r} and {b['model']!r}",
        )
    if a["size"] != b["size"]:
        raise _fail(
            where, f"cam{first} and cam{second} resolutions differ: {a['size']} and {b['size']}"
        )

    def link(n: int) -> np.ndarray:
        """cam{n}.T_cn_cnm1, checked."""
        key = f"cam{n}.T_cn_cnm1"
        m = _check_array(field(n, "T_cn_cnm1"), where, key, (4, 4))
        if m[3].tolist() != [0.0, 0.0, 0.0, 1.0]:
            raise _fail(where, f"{key} must end with the row 0 0 0 1, got {m[3].tolist()}")
        m[:3, :3] = _check_rotation(m[:3, :3], where, f"{key}[:3, :3]")
        return m

    lo, hi = min(first, second), max(first, second)
    chain = np.eye(4)
    for n in range(lo + 1, hi + 1):
        chain = link(n) @ chain  # from cam{lo} to cam{n}
    _check_implicit_baseline(
        float(np.linalg.norm(chain[:3, 3])),
        translation_unit,
        where,
        " @ ".join(f"cam{n}.T_cn_cnm1" for n in range(hi, lo, -1)),
        "Kalibr's convention",
    )
    if first > second:
        rot, tr = chain[:3, :3], chain[:3, 3]
        chain = np.eye(4)
        chain[:3, :3], chain[:3, 3] = rot.T, -rot.T @ tr
    return StereoCalibration(
        K1=a["K"],
        D1=a["D"],
        K2=b["K"],
        D2=b["D"],
        distortion_model=a["model"],
        R=chain[:3, :3],
        T=chain[:3, 3] * scale,
        image_size=_image_size_of(a["size"], image_size, where, "resolution"),
        source=where,
    )
