"""Reading calibration files: Middlebury's calib.txt, and every stereo calibration format
(OpenCV FileStorage YAML/XML, ROS camera_info, Kalibr, Middlebury, KITTI) into one
:class:`StereoCalibration`."""

from __future__ import annotations

import math
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from .rig import StereoRig

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


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_NUMBER_RE = re.compile(_NUMBER)
_INTEGER_RE = re.compile(r"\d+")
_LINE_RE = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)[ \t]*=[ \t]*(.*?)[ \t]*")


def _read_text(p: Path, what: str) -> str:
    """A calibration file's text: UTF-8 (a byte-order mark is dropped), any line ends."""
    if not p.is_file():
        raise FileNotFoundError(f"{what} not found: {p}")
    try:
        return p.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{p}: not a text file ({what}): {exc}") from exc


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
    return k


def read_middlebury_calib(path: str | os.PathLike[str]) -> MiddleburyCalib:
    """Parses a Middlebury ``calib.txt`` (the 2014 format, vision.middlebury.edu/stereo/data/
    scenes2014): one ``key=value`` a line, ``cam0=[f 0 cx; 0 f cy; 0 0 1]``, ``cam1=``,
    ``doffs=`` (px), ``baseline=`` (mm), ``width=``, ``height=``, ``ndisp=``, and keys this
    reader does not use (``isint``, ``vmin``, ``vmax``, ``dyavg``, ``dymax``, ...).

    Line ends LF, CR LF or CR; spaces around ``=`` and at line ends; blank lines. The format
    has no comments: any other line is refused. ``cam0`` and ``baseline`` are required,
    ``cam1`` defaults to ``cam0``, ``doffs`` to 0.

    Raises FileNotFoundError for a missing file and ValueError naming the file and the field
    (with the line number for a malformed line): a line that is not ``key=value``, a key
    given twice, a missing required key, a matrix that is not 3x3 with finite numbers,
    positive focal lengths and a last row 0 0 1, a baseline that is not a finite number
    > 0, a non-finite doffs, a width, height or ndisp that is not a whole number > 0."""
    p = Path(path)
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
        if _INTEGER_RE.fullmatch(v) is None or int(v) <= 0:
            raise ValueError(f"{p}: {key} must be a whole number > 0, got {v!r}")
        return int(v)

    cam0 = _matrix(fields["cam0"], "cam0", p)
    cam1 = _matrix(fields["cam1"], "cam1", p) if "cam1" in fields else cam0.copy()
    baseline = number("baseline")
    if not baseline > 0:
        raise ValueError(f"{p}: baseline must be > 0 mm, got {fields['baseline']!r}")
    doffs = number("doffs") if "doffs" in fields else 0.0
    return MiddleburyCalib(
        cam0=cam0,
        cam1=cam1,
        doffs_px=doffs,
        baseline_mm=baseline,
        width_px=whole("width"),
        height_px=whole("height"),
        ndisp=whole("ndisp"),
    )


# --- stereo calibration: one type for every calibration file ----------------------------------
# OpenCV FileStorage (YAML, XML), ROS camera_info pairs, Kalibr camchains, Middlebury, KITTI.
__all__ += [
    "StereoCalibration",
    "read_kalibr_stereo_calibration",
    "read_kitti_stereo_calibration",
    "read_middlebury_stereo_calibration",
    "read_opencv_stereo_calibration",
    "read_ros_stereo_calibration",
    "read_stereo_calibration",
]

#: Metres per unit of the translations in a calibration file (``translation_unit=``).
TRANSLATION_UNITS: dict[str, float] = {
    "m": 1.0,
    "cm": 0.01,
    "mm": 0.001,
    "um": 1e-6,
    "in": 0.0254,
    "ft": 0.3048,
}
#: The number of distortion coefficients each model takes.
DISTORTION_COUNTS: dict[str, tuple[int, ...]] = {
    "none": (0,),
    "plumb_bob": (4, 5, 8),
    "equidistant": (4,),
}
#: Names other tools give the models: ROS, Kalibr, OpenCV's fisheye module.
_MODEL_ALIASES = {
    "none": "none",
    "plumb_bob": "plumb_bob",
    "radtan": "plumb_bob",
    "rational_polynomial": "plumb_bob",
    "equidistant": "equidistant",
    "fisheye": "equidistant",
}
#: Models whose name fixes the number of coefficients.
_NAMED_COUNTS = {"rational_polynomial": (8,), "radtan": (4,)}
#: How close R R^T must be to I and det R to +1.
ROTATION_TOLERANCE = 1e-6


def _fail(where: str, message: str) -> ValueError:
    return ValueError(f"{where}: {message}")


def _check_array(value: Any, where: str, key: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (a vector also from (1, n) or (n, 1)),
    finite."""
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise _fail(where, f"{key} must be numbers, got {value!r}") from exc
    if len(shape) == 1 and a.ndim == 2 and 1 in a.shape:
        a = a.reshape(-1)
    if a.shape != shape and not (len(shape) == 1 and shape[0] < 0 and a.ndim == 1):
        want = "(n,)" if shape[0] < 0 else str(shape)
        raise _fail(where, f"{key} must have shape {want}, got {a.shape}")
    if not np.isfinite(a).all():
        raise _fail(where, f"{key} must be finite, got {a.tolist()}")
    return a


def _check_intrinsics(value: Any, where: str, key: str) -> np.ndarray:
    k = _check_array(value, where, key, (3, 3))
    if not (k[0, 0] > 0 and k[1, 1] > 0):
        raise _fail(where, f"{key} focal lengths must be > 0, got fx={k[0, 0]}, fy={k[1, 1]}")
    if k[1, 0] != 0 or k[2].tolist() != [0.0, 0.0, 1.0]:
        raise _fail(where, f"{key} must be [fx s cx; 0 fy cy; 0 0 1], got {k.tolist()}")
    return k


def _check_rotation(value: Any, where: str, key: str) -> np.ndarray:
    r = _check_array(value, where, key, (3, 3))
    err = float(np.abs(r @ r.T - np.eye(3)).max())
    det = float(np.linalg.det(r))
    if err > ROTATION_TOLERANCE or abs(det - 1.0) > ROTATION_TOLERANCE:
        raise _fail(
            where,
            f"{key} must be a rotation (R R^T = I and det R = +1 within {ROTATION_TOLERANCE:g}), "
            f"got max |R R^T - I| = {err:.3g} and det R = {det:.9g}",
        )
    return r


def _check_distortion(
    value: Any, model: str, where: str, key: str, named: str | None = None
) -> np.ndarray:
    """Distortion coefficients of ``model``; ``named`` the file's own name for the model,
    where it fixes the count (ROS's rational_polynomial 8, Kalibr's radtan 4)."""
    d = _check_array(value, where, key, (-1,))
    name = named.strip().lower() if named is not None else model
    counts = _NAMED_COUNTS.get(name, DISTORTION_COUNTS[model])
    if d.size not in counts:
        takes = " or ".join(str(c) for c in counts)
        raise _fail(where, f"{key} has {d.size} coefficients; the {name} model takes {takes}")
    return d


def _check_model(value: Any, where: str, key: str) -> str:
    if not isinstance(value, str) or value.strip().lower() not in _MODEL_ALIASES:
        known = ", ".join(sorted(_MODEL_ALIASES))
        raise _fail(where, f"{key} must be one of {known}, got {value!r}")
    return _MODEL_ALIASES[value.strip().lower()]


def _check_image_size(value: Any, where: str, key: str) -> tuple[int, int]:
    if isinstance(value, np.ndarray):
        value = value.reshape(-1).tolist()
    if not isinstance(value, list | tuple) or len(value) != 2:
        raise _fail(where, f"{key} must be (width, height), got {value!r}")
    w, h = value
    out = []
    for v in (w, h):
        f = _to_float(v)
        if f is None or not (f.is_integer() and f > 0):
            raise _fail(where, f"{key} must be two whole numbers > 0, got {value!r}")
        out.append(int(f))
    return out[0], out[1]


def _to_float(v: Any) -> float | None:
    """A number from a parsed file: int or float (not bool), or a string that spells one
    (PyYAML leaves ``1e-05`` and OpenCV's ``.Nan`` as strings)."""
    if isinstance(v, bool | np.bool_):
        return None
    if isinstance(v, int | float | np.integer | np.floating):
        return float(v)
    if isinstance(v, str):
        s = v.strip()
        if _NUMBER_RE.fullmatch(s):
            return float(s)
        special = {".nan": math.nan, ".inf": math.inf, "+.inf": math.inf, "-.inf": -math.inf}
        return special.get(s.lower())
    return None


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """A calibrated stereo pair, in OpenCV's conventions, from any calibration file.

    A point X in the left camera's frame is ``R @ X + T`` in the right camera's frame (what
    ``cv2.stereoCalibrate`` returns). Every array is float64; the readers check the shapes,
    that every value is finite, that the rotations are rotations (``R R^T = I`` and
    ``det R = +1`` within 1e-6) and that the distortion coefficients fit the model, and
    raise ValueError naming the file and the key otherwise; building one directly runs the
    same checks and names the field.

    Fields:
        K1, K2: (3, 3) intrinsics of the left and right camera, pixels.
        D1, D2: (n,) distortion coefficients: none for ``"none"``; k1 k2 p1 p2 [k3 [k4 k5
            k6]] (4, 5 or 8) for ``"plumb_bob"`` (Brown-Conrady, ROS's plumb_bob and
            rational_polynomial, Kalibr's radtan, OpenCV's default model); k1 k2 k3 k4 for
            ``"equidistant"`` (Kannala-Brandt, OpenCV's fisheye module, Kalibr's
            equidistant).
        distortion_model: ``"none"``, ``"plumb_bob"`` or ``"equidistant"``, both cameras.
        R: (3, 3) rotation from the left camera to the right.
        T: (3,) translation from the left camera to the right, metres (for a right camera
            at baseline B to the right of the left one, about (-B, 0, 0)).
        image_size: (width, height) of the images in pixels.
        R1, R2, P1, P2, Q: the rectification (3, 3), projections (3, 4) and disparity-to-
            depth matrix (4, 4) of ``cv2.stereoRectify``, where the source holds them (P's
            last column and Q in metres, as T), else None.
        rectified: True for already rectified sources (Middlebury, KITTI): R is the identity,
            the distortion ``"none"``, and R1, R2, P1, P2, Q are filled in.
        source: the file or files it was read from.
    """

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    distortion_model: str
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]
    R1: np.ndarray | None = None
    R2: np.ndarray | None = None
    P1: np.ndarray | None = None
    P2: np.ndarray | None = None
    Q: np.ndarray | None = None
    rectified: bool = False
    source: str = ""

    def __post_init__(self) -> None:
        where = self.source or "StereoCalibration"
        model = _check_model(self.distortion_model, where, "distortion_model")
        fields: dict[str, Any] = {
            "distortion_model": model,
            "K1": _check_intrinsics(self.K1, where, "K1"),
            "K2": _check_intrinsics(self.K2, where, "K2"),
            "D1": _check_distortion(self.D1, model, where, "D1"),
            "D2": _check_distortion(self.D2, model, where, "D2"),
            "R": _check_rotation(self.R, where, "R"),
            "T": _check_array(self.T, where, "T", (3,)),
            "image_size": _check_image_size(self.image_size, where, "image_size"),
        }
        if not np.any(fields["T"]):
            raise _fail(where, "T must not be zero (the cameras are at the same place)")
        for key, shape in (
            ("R1", None),
            ("R2", None),
            ("P1", (3, 4)),
            ("P2", (3, 4)),
            ("Q", (4, 4)),
        ):
            value = getattr(self, key)
            if value is not None:
                fields[key] = (
                    _check_rotation(value, where, key)
                    if shape is None
                    else _check_array(value, where, key, shape)
                )
                if key in ("P1", "P2"):
                    _check_intrinsics(fields[key][:, :3], where, f"{key}[:, :3]")
        if not isinstance(self.rectified, bool):
            raise TypeError(f"rectified must be a bool, got {self.rectified!r}")
        if not isinstance(self.source, str):
            raise TypeError(f"source must be a str, got {self.source!r}")
        if self.rectified and not (np.array_equal(fields["R"], np.eye(3)) and model == "none"):
            raise _fail(
                where, "a rectified calibration has R = identity and distortion_model 'none'"
            )
        for key, value in fields.items():
            object.__setattr__(self, key, value)

    @property
    def baseline_m(self) -> float:
        """The distance between the two camera centres, metres: the norm of T."""
        return float(np.linalg.norm(self.T))

    def to_rig(self) -> StereoRig:
        """The :class:`~stereodepth.StereoRig` of the rectified pair (focal length, baseline,
        principal point offset doffs and image size), for computing depth from disparity.

        For a rectified source (``rectified=True``): focal length K1's fx, baseline -T[0],
        doffs K2's cx - K1's cx. For a source that holds the rectified projections P1, P2 (as
        OpenCV and ROS stereo calibrations do): focal length P1's fx, baseline
        -(P2[0, 3] - P1[0, 3]) / P2's fx, doffs P2's cx - P1's cx. Raises ValueError for any
        other calibration (rectify it first: the rectified pair's rig comes with the
        rectification), for a vertical pair and when the right camera is not to the right."""
        from .rig import StereoRig

        where = self.source or "StereoCalibration"
        if self.rectified:
            k1, k2, t = self.K1, self.K2, self.T
            if k1[0, 0] != k2[0, 0] or k1[1, 1] != k2[1, 1] or k1[1, 2] != k2[1, 2]:
                raise _fail(where, "a rectified pair has the same fx, fy and cy in K1 and K2")
            if abs(t[1]) > 1e-9 * abs(t[0]) or abs(t[2]) > 1e-9 * abs(t[0]):
                raise _fail(where, f"a rectified horizontal pair has T = (-B, 0, 0), got {t}")
            focal, baseline, doffs = k1[0, 0], -t[0], k2[0, 2] - k1[0, 2]
        elif self.P1 is not None and self.P2 is not None:
            p1, p2 = self.P1, self.P2
            if p2[1, 3] != p1[1, 3]:
                raise _fail(
                    where,
                    "P2 is of a vertical pair (P2[1, 3] != 0): the matchers need a horizontal one",
                )
            focal = p1[0, 0]
            baseline = -(p2[0, 3] - p1[0, 3]) / p2[0, 0]
            doffs = p2[0, 2] - p1[0, 2]
        else:
            raise _fail(
                where,
                "this calibration is not rectified and holds no P1, P2: rectify the pair "
                "first (the rectified pair's rig comes with the rectification)",
            )
        if not baseline > 0:
            raise _fail(
                where,
                f"the right camera must be to the right of the left one, got a "
                f"baseline of {baseline!r} m",
            )
        return StereoRig.from_pixels(
            baseline_mm=float(baseline) * 1000.0,
            focal_px=float(focal),
            width_px=self.image_size[0],
            height_px=self.image_size[1],
            doffs_px=float(doffs),
        )


def _rectified_matrices(k1: np.ndarray, k2: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
    """R1, R2, P1, P2, Q of an already rectified horizontal pair, as cv2.stereoRectify lays
    them out (Q[3, 3] = (cx1 - cx2) / Tx keeps a principal point offset)."""
    p1 = np.hstack([k1, np.zeros((3, 1))])
    p2 = np.hstack([k2, (k2 @ t).reshape(3, 1)])
    tx = t[0]
    q = np.array(
        [
            [1.0, 0.0, 0.0, -k1[0, 2]],
            [0.0, 1.0, 0.0, -k1[1, 2]],
            [0.0, 0.0, 0.0, k1[0, 0]],
            [0.0, 0.0, -1.0 / tx, (k1[0, 2] - k2[0, 2]) / tx],
        ]
    )
    return {"R1": np.eye(3), "R2": np.eye(3), "P1": p1, "P2": p2, "Q": q}


def _unit(translation_unit: str) -> float:
    if translation_unit not in TRANSLATION_UNITS:
        known = ", ".join(repr(u) for u in TRANSLATION_UNITS)
        raise ValueError(f"translation_unit must be one of {known}, got {translation_unit!r}")
    return TRANSLATION_UNITS[translation_unit]


def _image_size_of(
    found: tuple[int, int] | None, given: Any, where: str, hint: str
) -> tuple[int, int]:
    """The image size from the file and/or the caller, which must agree when both are set."""
    if given is not None:
        given = _check_image_size(given, "image_size", "image_size")
    if found is not None and given is not None and found != given:
        raise _fail(where, f"the file gives an image size of {found}, image_size= {given}")
    size = found or given
    if size is None:
        raise _fail(where, f"no image size in the file ({hint}): pass image_size=(width, height)")
    return size


# --- YAML and XML as trees of dicts, lists, numbers, strings and arrays --------------------------
def _yaml() -> Any:
    try:
        import yaml
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            'reading YAML calibration files needs PyYAML: pip install "stereodepth[calib]"'
        ) from exc
    return yaml


def _opencv_matrix(node: Any, where: str, key: str) -> np.ndarray:
    """An ``opencv-matrix`` (rows, cols, dt, data) as a float64 (rows, cols[, channels]), or
    an ``opencv-nd-matrix`` (sizes, dt, data) as a float64 array of shape sizes[+ channels]."""
    if not isinstance(node, dict):
        raise _fail(where, f"{key}: an opencv-matrix must be a mapping, got {node!r}")
    dims = ("sizes",) if "sizes" in node else ("rows", "cols")
    missing = [k for k in (*dims, "dt", "data") if k not in node]
    if missing:
        raise _fail(where, f"{key}: opencv-matrix without {', '.join(missing)}")
    sizes = node["sizes"] if dims == ("sizes",) else [node["rows"], node["cols"]]
    sizes = sizes if isinstance(sizes, list) else [sizes]
    shape: list[int] = []
    for name, v in zip(dims * len(sizes) if dims == ("sizes",) else dims, sizes, strict=True):
        f = _to_float(v)
        if f is None or not (f.is_integer() and f >= 0):
            raise _fail(where, f"{key}: opencv-matrix {name} must be whole numbers >= 0, got {v!r}")
        shape.append(int(f))
    dt = node["dt"]
    m = re.fullmatch(r"(\d*)([ucwsifdh])", str(dt).strip('"'))
    if m is None:
        raise _fail(where, f"{key}: opencv-matrix dt must be a type such as 'd' or 'f', got {dt!r}")
    channels = int(m.group(1) or 1)
    if channels != 1:
        shape.append(channels)
    data = node["data"]
    if isinstance(data, str | int | float):
        data = [data]
    if not isinstance(data, list):
        raise _fail(where, f"{key}: opencv-matrix data must be a list of numbers, got {data!r}")
    values = [_to_float(v) for v in data]
    bad = [v for v, f in zip(data, values, strict=True) if f is None]
    if bad:
        raise _fail(where, f"{key}: opencv-matrix data must be numbers, got {bad[0]!r}")
    count = math.prod(shape)
    if len(values) != count:
        raise _fail(
            where,
            f"{key}: opencv-matrix of {'x'.join(map(str, shape))} needs {count} values, "
            f"got {len(values)}",
        )
    return np.array(values, dtype=np.float64).reshape(shape)


def _yaml_tree(p: Path, text: str) -> dict[str, Any]:
    """A YAML file as a dict, also OpenCV's: the ``%YAML:1.0`` directive (which YAML parsers
    reject) dropped, ``!!opencv-matrix`` nodes as arrays. Duplicate keys are refused."""
    yaml = _yaml()
    where = str(p)

    class Loader(yaml.SafeLoader):  # type: ignore[misc, name-defined]
        pass

    class RawMatrix(dict):  # type: ignore[type-arg]
        """An ``!!opencv-matrix`` node, converted once its key is known."""

    def mapping(loader: Any, node: Any) -> dict[Any, Any]:
        out: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = loader.construct_object(key_node, deep=True)
            if not isinstance(key, str | int | float):
                raise _fail(where, f"keys must be names, got {key!r}")
            if key in out:
                raise _fail(where, f"{key} is given twice (line {key_node.start_mark.line + 1})")
            value = loader.construct_object(value_node, deep=True)
            out[key] = _opencv_matrix(value, where, str(key)) if type(value) is RawMatrix else value
        return out

    def matrix(loader: Any, node: Any) -> RawMatrix:
        return RawMatrix(mapping(loader, node))

    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", matrix)
    Loader.add_constructor("tag:yaml.org,2002:opencv-nd-matrix", matrix)
    # OpenCV writes "%YAML:1.0" (before 5.0; "%YAML 1.2" since): a YAML 1.1 parser wants
    # neither. Blank the line, keeping the line numbers of error messages.
    text = re.sub(r"\A%YAML[: ]?[ \t]*\d+\.\d+[ \t]*", "", text)
    try:
        tree = yaml.load(text, Loader=Loader)  # a SafeLoader: no arbitrary objects
    except yaml.YAMLError as exc:
        raise _fail(where, f"not valid YAML: {' '.join(str(exc).split())}") from exc
    if not isinstance(tree, dict):
        raise _fail(where, f"a calibration file must be a YAML mapping, got {type(tree).__name__}")
    return tree


def _xml_value(el: ET.Element, where: str) -> Any:
    key = el.tag
    if el.get("type_id") in ("opencv-matrix", "opencv-nd-matrix"):
        node = {c.tag: (c.text or "").split() for c in el}
        flat: dict[str, Any] = {
            k: (v[0] if k != "data" and len(v) == 1 else v) for k, v in node.items()
        }
        return _opencv_matrix(flat, where, key)
    children = list(el)
    if children:
        if all(c.tag == "_" for c in children):
            return [_xml_value(c, where) for c in children]
        out: dict[str, Any] = {}
        for c in children:
            if c.tag in out:
                raise _fail(where, f"{c.tag} is given twice")
            out[c.tag] = _xml_value(c, where)
        return out
    words = (el.text or "").split()
    numbers = [_to_float(w) for w in words]
    if words and all(n is not None for n in numbers):
        vals = [
            int(n) if n is not None and n.is_integer() and "." not in w else n
            for n, w in zip(numbers, words, strict=True)
        ]
        return vals[0] if len(vals) == 1 else vals
    return " ".join(words).strip('"')


def _xml_tree(p: Path, text: str) -> dict[str, Any]:
    """An OpenCV FileStorage XML file (``<opencv_storage>``) as a dict, matrices as arrays."""
    where = str(p)
    if re.search(r"<!(DOCTYPE|ENTITY)", text):
        raise _fail(where, "XML with a DOCTYPE or entities is not an OpenCV FileStorage file")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise _fail(where, f"not valid XML: {exc}") from exc
    if root.tag != "opencv_storage":
        raise _fail(where, f"the XML root must be <opencv_storage>, got <{root.tag}>")
    tree = _xml_value(root, where)
    return tree if isinstance(tree, dict) else {}


def _lookup(tree: dict[str, Any], names: tuple[str, ...], where: str) -> tuple[str, Any] | None:
    """The one key of ``names`` present in ``tree`` (None if none; ValueError if several)."""
    found = [n for n in names if n in tree]
    if len(found) > 1:
        raise _fail(where, f"both {found[0]} and {found[1]} are given: which one holds the matrix?")
    return (found[0], tree[found[0]]) if found else None


def _require(tree: dict[str, Any], names: tuple[str, ...], where: str) -> tuple[str, Any]:
    hit = _lookup(tree, names, where)
    if hit is None:
        raise _fail(where, f"missing key {' or '.join(names)}")
    return hit


def _file_image_size(tree: dict[str, Any], where: str) -> tuple[int, int] | None:
    """The image size under the names calibration tools use, if any."""
    hit = _lookup(tree, ("image_size", "imageSize", "img_size", "resolution"), where)
    if hit is not None:
        key, value = hit
        return _check_image_size(value, where, key)
    for wk, hk in (
        ("image_width", "image_height"),
        ("imageWidth", "imageHeight"),
        ("width", "height"),
    ):
        if wk in tree or hk in tree:
            if wk not in tree or hk not in tree:
                raise _fail(
                    where, f"{wk} and {hk} go together, got only {wk if wk in tree else hk}"
                )
            return _check_image_size((tree[wk], tree[hk]), where, f"{wk}, {hk}")
    return None


def _read_tree(p: Path, what: str) -> tuple[str, dict[str, Any]]:
    text = _read_text(p, what)
    head = text.lstrip()
    if head.startswith(("<?xml", "<opencv_storage")):
        return "xml", _xml_tree(p, text)
    return "yaml", _yaml_tree(p, text)


def _ros_matrix(tree: dict[str, Any], key: str, where: str, shape: tuple[int, ...]) -> np.ndarray:
    """A ROS camera_info matrix: ``{rows, cols, data}``."""
    if key not in tree:
        raise _fail(where, f"missing key {key}")
    node = tree[key]
    if isinstance(node, dict) and "data" in node:
        data = node["data"]
        rows, cols = node.get("rows"), node.get("cols")
        if not isinstance(data, list):
            raise _fail(where, f"{key}.data must be a list of numbers, got {data!r}")
        values = [_to_float(v) for v in data]
        if any(v is None for v in values):
            raise _fail(where, f"{key}.data must be numbers, got {data!r}")
        r, c = _to_float(rows), _to_float(cols)
        if r is None or c is None or not (r.is_integer() and c.is_integer()) or r < 0 or c < 0:
            raise _fail(where, f"{key} rows and cols must be whole numbers, got {rows!r}, {cols!r}")
        if len(values) != r * c:
            raise _fail(
                where, f"{key} of {int(r)}x{int(c)} needs {int(r * c)} values, got {len(values)}"
            )
        a = np.array(values, dtype=np.float64).reshape(int(r), int(c))
    elif isinstance(node, np.ndarray):
        a = node
    else:
        raise _fail(where, f"{key} must be a mapping with rows, cols and data, got {node!r}")
    return _check_array(a, where, key, shape)


def _numbers(value: Any, where: str, key: str) -> list[float]:
    if not isinstance(value, list):
        raise _fail(where, f"{key} must be a list of numbers, got {value!r}")
    out = [_to_float(v) for v in value]
    if any(v is None for v in out):
        raise _fail(where, f"{key} must be a list of numbers, got {value!r}")
    return [float(v) for v in out if v is not None]


# --- the readers ----------------------------------------------------------------------------------
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


def read_opencv_stereo_calibration(
    path: str | os.PathLike[str],
    extrinsics_path: str | os.PathLike[str] | None = None,
    *,
    translation_unit: str = "m",
    image_size: tuple[int, int] | None = None,
    distortion_model: str | None = None,
) -> StereoCalibration:
    """A stereo calibration saved with ``cv2.FileStorage`` (YAML or XML) after
    ``cv2.stereoCalibrate`` (and ``cv2.stereoRectify``), as OpenCV's stereo_calib sample and
    most scripts write it: ``M1``/``K1``/``cameraMatrix1``, ``D1``/``distCoeffs1``, the same
    for camera 2, ``R``, ``T``, and optionally ``R1``, ``R2``, ``P1``, ``P2``, ``Q``, the image
    size (``image_size``/``imageSize`` as (width, height), or ``image_width`` and
    ``image_height``) and ``distortion_model``. OpenCV's stereo_calib sample writes two files,
    intrinsics.yml and extrinsics.yml: pass the second as ``extrinsics_path`` (a key in both
    is refused).

    YAML needs PyYAML (``pip install "stereodepth[calib]"``); OpenCV's ``%YAML:1.0``
    directive and ``!!opencv-matrix`` tags are understood. XML is read with
    ``xml.etree`` (files with a DOCTYPE are refused).

    Units: OpenCV's T (and P2's last column, Q's last row) is in the unit of the
    calibration target's square size, which the file does not record: ``translation_unit``
    says which it is (``"m"``, the default, ``"cm"``, ``"mm"``, ``"um"``, ``"in"``, ``"ft"``)
    and T is converted to metres. Distortion: 4, 5 or 8 coefficients are the plumb_bob
    (radtan) model unless the file's ``distortion_model`` or ``distortion_model=`` says
    ``"equidistant"`` (``cv2.fisheye`` calibrations: 4 coefficients look the same); OpenCV's
    12 and 14 coefficient forms are accepted when the thin prism and tilt terms are 0.

    Raises FileNotFoundError for a missing file, ImportError without PyYAML, ValueError
    naming the file and the key for a missing key, a wrong shape, a non-finite value, a
    rotation that is not one, a distortion count that does not fit the model, or an image
    size that is missing (pass ``image_size=``) or disagrees with ``image_size=``."""
    scale = _unit(translation_unit)
    paths = [Path(path)] + ([Path(extrinsics_path)] if extrinsics_path is not None else [])
    tree: dict[str, Any] = {}
    origin: dict[str, str] = {}
    for p in paths:
        _, t = _read_tree(p, "OpenCV calibration file")
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
    out: dict[str, Any] = {}
    for field in ("K1", "K2"):
        key, value, where = get(field)  # type: ignore[misc]
        out[field] = _check_intrinsics(value, where, key)
    for field in ("D1", "D2"):
        key, value, where = get(field)  # type: ignore[misc]
        d = _check_array(value, where, key, (-1,))
        if model == "plumb_bob" and d.size in (12, 14):
            if np.any(d[8:]):
                raise _fail(
                    where,
                    f"{key} has thin prism or tilt terms (coefficients 9 to {d.size}), "
                    "which the plumb_bob model does not take",
                )
            d = d[:8]
        out[field] = _check_distortion(d, model, where, key)
    key, value, where = get("R")  # type: ignore[misc]
    out["R"] = _check_rotation(value, where, key)
    key, value, where = get("T")  # type: ignore[misc]
    out["T"] = _check_array(value, where, key, (3,)) * scale
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


def _ros_camera(p: Path, scale: float) -> dict[str, Any]:
    where = str(p)
    tree = _yaml_tree(p, _read_text(p, "ROS camera_info file"))
    k = _check_intrinsics(_ros_matrix(tree, "camera_matrix", where, (3, 3)), where, "camera_matrix")
    if "distortion_model" not in tree:
        raise _fail(where, "missing key distortion_model")
    model = _check_model(tree["distortion_model"], where, "distortion_model")
    d = _ros_matrix(tree, "distortion_coefficients", where, (-1,))
    d = _check_distortion(
        d, model, where, "distortion_coefficients", named=tree["distortion_model"]
    )
    r = _check_rotation(
        _ros_matrix(tree, "rectification_matrix", where, (3, 3)), where, "rectification_matrix"
    )
    pm = _ros_matrix(tree, "projection_matrix", where, (3, 4))
    kp = _check_intrinsics(pm[:, :3], where, "projection_matrix[:, :3]")
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
    translation_unit: str = "m",
    image_size: tuple[int, int] | None = None,
) -> StereoCalibration:
    """A stereo calibration from the two ROS camera_info YAML files of a rectified pair, as
    ROS's camera_calibration writes them (wiki.ros.org/camera_calibration_parsers,
    sensor_msgs/CameraInfo): ``image_width``, ``image_height``, ``camera_matrix``,
    ``distortion_model`` (``plumb_bob``, ``rational_polynomial``, ``equidistant``),
    ``distortion_coefficients``, ``rectification_matrix`` and ``projection_matrix``, each
    matrix as ``{rows, cols, data}``.

    ROS stores no R and T: they are recovered from the rectification. Each rectified camera
    i has ``P_i = K'_i [I | t_i]`` (for the right camera of a horizontal pair ``Tx = -fx' B``,
    so t = (-B, 0, 0)); a point X of the left camera is ``R1 X - t_1`` in the common
    rectified frame, so ``R = R2^T R1`` and ``T = R2^T (t_2 - t_1)``. The two projections
    must share fx' and fy' (a rectified pair). B is in metres by ROS's convention;
    ``translation_unit`` says otherwise. R1, R2, P1, P2 are the files' rectification and
    projection matrices.

    Raises FileNotFoundError, ImportError without PyYAML, and ValueError naming the file
    and the key for a missing key, a wrong shape, a non-finite value, a rectification matrix
    that is not a rotation, a distortion count that does not fit the model, cameras with
    different distortion models, image sizes or rectified focal lengths, a right camera
    with no offset or files given in the wrong order."""
    scale = _unit(translation_unit)
    left = _ros_camera(Path(left_path), scale)
    right = _ros_camera(Path(right_path), scale)
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
            "(are the files swapped?)",
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


def _check_cameras(cameras: Any, name: str = "cameras") -> tuple[int, int]:
    try:
        a, b = cameras
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be two camera numbers, got {cameras!r}") from None
    for c in (a, b):
        if isinstance(c, bool) or not isinstance(c, int) or c < 0:
            raise ValueError(f"{name} must be two whole numbers >= 0, got {cameras!r}")
    if a == b:
        raise ValueError(f"{name} must be two different cameras, got {cameras!r}")
    return a, b


def read_kalibr_stereo_calibration(
    path: str | os.PathLike[str],
    *,
    cameras: tuple[int, int] = (0, 1),
    translation_unit: str = "m",
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
    the chain are composed. ``translation_unit`` is "m" by Kalibr's convention.

    Raises FileNotFoundError, ImportError without PyYAML, and ValueError naming the file
    and the key (``cam1.T_cn_cnm1``) for a missing key, a wrong shape, a non-finite value, a
    transform whose rotation is not one or whose last row is not 0 0 0 1, an unsupported
    camera model, a distortion count that does not fit the model, and cameras with
    different distortion models or resolutions."""
    scale = _unit(translation_unit)
    first, second = _check_cameras(cameras)
    p = Path(path)
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
        _check_rotation(m[:3, :3], where, f"{key}[:3, :3]")
        return m

    lo, hi = min(first, second), max(first, second)
    chain = np.eye(4)
    for n in range(lo + 1, hi + 1):
        chain = link(n) @ chain  # from cam{lo} to cam{n}
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


def _rectified_calibration(
    k1: np.ndarray, k2: np.ndarray, baseline_m: float, size: tuple[int, int], where: str
) -> StereoCalibration:
    t = np.array([-baseline_m, 0.0, 0.0])
    return StereoCalibration(
        K1=k1,
        D1=np.zeros(0),
        K2=k2,
        D2=np.zeros(0),
        distortion_model="none",
        R=np.eye(3),
        T=t,
        image_size=size,
        rectified=True,
        source=where,
        **_rectified_matrices(k1, k2, t),
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
    p = Path(path)
    c = read_middlebury_calib(p)
    found = (c.width_px, c.height_px) if c.width_px and c.height_px else None
    size = _image_size_of(found, image_size, str(p), "width, height")
    return _rectified_calibration(c.cam0, c.cam1, c.baseline_mm / 1000.0, size, str(p))


def read_kitti_stereo_calibration(
    path: str | os.PathLike[str],
    *,
    cameras: tuple[int, int] = (2, 3),
    image_size: tuple[int, int] | None = None,
) -> StereoCalibration:
    """A KITTI calibration file as a rectified :class:`StereoCalibration` of two of its
    cameras (default 2 and 3, the colour pair): ``P2: ...`` lines as in KITTI 2012/2015's
    ``calib/*.txt``, or ``P_rect_02: ...`` as in ``calib_cam_to_cam.txt`` (whose
    ``S_rect_02`` gives the image size; otherwise pass ``image_size=``).

    One ``key: value`` a line (other keys are skipped), each projection 12 finite numbers.
    K_i is P_i's left 3x3, no distortion, R = I, and T = (-B, 0, 0) with the baseline
    ``B = (P_left[0, 3] - P_right[0, 3]) / fx`` in metres, as KITTI's development kit computes
    it (the sub-millimetre y and z offsets in the projections are dropped); R1, R2, P1, P2,
    Q as ``cv2.stereoRectify`` lays them out, relative to the left camera.

    Raises FileNotFoundError, and ValueError naming the file and the key for a line that is
    not ``key: value``, a key given twice, a missing or malformed projection, cameras that
    do not share fx, fy and cy, a right camera not to the right, and an image size that is
    missing or disagrees with ``image_size=``."""
    first, second = _check_cameras(cameras)
    p = Path(path)
    where = str(p)
    fields: dict[str, tuple[int, str]] = {}
    for lineno, line in enumerate(_read_text(p, "KITTI calibration file").splitlines(), 1):
        if not line.strip():
            continue
        m = re.fullmatch(r"[ \t]*([A-Za-z_][A-Za-z0-9_]*)[ \t]*:[ \t]*(.*?)[ \t]*", line)
        if m is None:
            raise _fail(
                where, f"line {lineno} of a KITTI calibration must be key: value, got {line!r}"
            )
        if m.group(1) in fields:
            raise _fail(where, f"{m.group(1)} is given twice (line {lineno})")
        fields[m.group(1)] = (lineno, m.group(2))

    def numbers(key: str, count: int) -> np.ndarray:
        lineno, text = fields[key]
        words = text.split()
        if len(words) != count or not all(_NUMBER_RE.fullmatch(w) for w in words):
            raise _fail(where, f"{key} (line {lineno}) must be {count} numbers, got {text!r}")
        return _check_array([float(w) for w in words], where, key, (count,))

    proj: dict[int, tuple[str, np.ndarray]] = {}
    for c in (first, second):
        keys = [k for k in (f"P{c}", f"P_rect_0{c}") if k in fields]
        if not keys:
            raise _fail(where, f"missing key P{c} (or P_rect_0{c})")
        if len(keys) > 1:
            raise _fail(where, f"both {keys[0]} and {keys[1]} are given")
        pm = numbers(keys[0], 12).reshape(3, 4)
        _check_intrinsics(pm[:, :3], where, f"{keys[0]}[:, :3]")
        proj[c] = (keys[0], pm)
    (kl, pl), (kr, pr) = proj[first], proj[second]
    for i, j, name in ((0, 0, "fx"), (1, 1, "fy"), (1, 2, "cy")):
        if pl[i, j] != pr[i, j]:
            raise _fail(
                where,
                f"{kl} and {kr} must share {name} (a rectified pair), got {pl[i, j]} and "
                f"{pr[i, j]}",
            )
    baseline = float(pl[0, 3] - pr[0, 3]) / pl[0, 0]
    if not baseline > 0:
        raise _fail(
            where,
            f"camera {second} must be right of camera {first}, got a baseline of {baseline} m",
        )
    size_key = f"S_rect_0{first}"
    found = None
    if size_key in fields:
        found = _check_image_size(numbers(size_key, 2).tolist(), where, size_key)
    size = _image_size_of(found, image_size, where, size_key)
    return _rectified_calibration(pl[:, :3].copy(), pr[:, :3].copy(), baseline, size, where)


def read_stereo_calibration(
    path: str | os.PathLike[str],
    *,
    second_path: str | os.PathLike[str] | None = None,
    translation_unit: str = "m",
    image_size: tuple[int, int] | None = None,
    distortion_model: str | None = None,
    cameras: tuple[int, int] | None = None,
) -> StereoCalibration:
    """A stereo calibration from any file this module reads, the format told by content:

    - OpenCV FileStorage XML (``<opencv_storage>``) or YAML (keys such as M1, K1, R, T):
      :func:`read_opencv_stereo_calibration`, ``second_path`` the second file when the
      calibration is split in two (intrinsics and extrinsics);
    - ROS camera_info YAML (``camera_matrix``): :func:`read_ros_stereo_calibration`, the
      left camera's file, ``second_path`` the right camera's (required);
    - Kalibr camchain YAML (``cam0`` with ``intrinsics``):
      :func:`read_kalibr_stereo_calibration`;
    - Middlebury ``calib.txt`` (``cam0=[...]``): :func:`read_middlebury_stereo_calibration`;
    - KITTI (``P2: ...`` or ``P_rect_02: ...`` lines): :func:`read_kitti_stereo_calibration`.

    The keywords go to the readers that take them: ``translation_unit`` (OpenCV, ROS,
    Kalibr; Middlebury and KITTI files state their unit, so only "m" is accepted there),
    ``image_size`` (all), ``distortion_model`` (OpenCV), ``cameras`` (Kalibr, default (0, 1);
    KITTI, default (2, 3)). Raises FileNotFoundError, ValueError naming the file for an
    unknown format, a keyword that does not apply or any fault the reader finds, and
    ImportError when a YAML file needs PyYAML."""
    p = Path(path)
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
    if re.search(r"^[ \t]*cam0[ \t]*=", text, flags=re.MULTILINE):
        refuse(
            "Middlebury",
            second_path=second_path,
            distortion_model=distortion_model,
            cameras=cameras,
            translation_unit=translation_unit != "m",
        )
        return read_middlebury_stereo_calibration(p, image_size=image_size)
    if re.search(r"^[ \t]*P(_rect_0)?\d[ \t]*:[ \t]*[-+.\d]", text, flags=re.MULTILINE):
        refuse(
            "KITTI",
            second_path=second_path,
            distortion_model=distortion_model,
            translation_unit=translation_unit != "m",
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
    if "camera_matrix" in tree:
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
