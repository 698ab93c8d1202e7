"""What every calibration reader shares: reading text, numbers, checks of arrays, rotations,
distortion models, units and image sizes."""

from __future__ import annotations

import math
import re
import reprlib
from pathlib import Path
from typing import Any

import numpy as np

from ..io import _as_path

# A reader's path argument as a Path, or TypeError naming the parameter (pathlib's own
# "expected str, bytes or os.PathLike object, not int" named none).
_path = _as_path

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


_NUMBER_RE = re.compile(_NUMBER)


_INTEGER_RE = re.compile(r"\d+")


_LINE_RE = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)[ \t]*=[ \t]*(.*?)[ \t]*")


def _limited_repr() -> reprlib.Repr:
    r = reprlib.Repr()
    r.maxlevel, r.maxlist, r.maxtuple, r.maxdict = 2, 16, 16, 8
    r.maxstring, r.maxother, r.maxlong = 120, 120, 60
    return r


_REPR = _limited_repr()


def _shown(value: Any) -> str:
    """``repr(value)`` for an error message, shortened (``...``) where it is long or deeply
    nested, so that a huge or hostile file gives a message of a few lines, not megabytes."""
    return _REPR.repr(value)


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


#: How close R R^T must be to I and det R to +1. Files print their rotations rounded: C++'s
#: default 6 significant digits (ROS camera_calibration_parsers, hand-copied files) leave
#: |R R^T - I| up to about 3e-6, and ROS's R = R2^T R1 composes two such roundings; 1e-5
#: accepts them and still refuses a matrix off by 1e-5 in every entry.
ROTATION_TOLERANCE = 1e-5


#: Within this |R R^T - I| (and |det R - 1|) a rotation is kept bit for bit: what the readers
#: took before, float32 files' rotations included, and what the rectifier's own check takes;
#: beyond it (and within ROTATION_TOLERANCE) it is replaced by the nearest rotation.
_EXACT_ROTATION = 1e-6


#: The largest calibration file read, bytes: the files of every format here are a few kB; a
#: larger file is another kind (a point cloud, a log) given by mistake, which the YAML parser
#: would take minutes over (about 3 s per MB).
MAX_FILE_BYTES = 4 * 1024 * 1024


def _read_text(p: Path, what: str) -> str:
    """A calibration file's text: UTF-8 (a byte-order mark is dropped), any line ends, at
    most :data:`MAX_FILE_BYTES`."""
    from ..io import require_file

    require_file(p, what)
    size = p.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ValueError(
            f"{p}: {size} bytes is too large for a {what} (at most {MAX_FILE_BYTES} bytes; "
            "calibration files are a few kB)"
        )
    try:
        return p.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{p}: not a text file ({what}): {exc}") from exc


def _fail(where: str, message: str) -> ValueError:
    return ValueError(f"{where}: {message}")


def _check_array(value: Any, where: str, key: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (a vector also from (1, n) or (n, 1), and
    an empty one from OpenCV's empty Mat, rows: 0 and cols: 0), finite."""
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise _fail(where, f"{key} must be numbers, got {_shown(value)}") from exc
    if len(shape) == 1 and a.ndim == 2 and (1 in a.shape or a.size == 0):
        a = a.reshape(-1)
    if a.shape != shape and not (len(shape) == 1 and shape[0] < 0 and a.ndim == 1):
        want = "(n,)" if shape[0] < 0 else str(shape)
        raise _fail(where, f"{key} must have shape {want}, got {a.shape}")
    if not np.isfinite(a).all():
        raise _fail(where, f"{key} must be finite, got {_shown(a.tolist())}")
    return a


def _check_intrinsics(value: Any, where: str, key: str) -> np.ndarray:
    k = _check_array(value, where, key, (3, 3))
    if not (k[0, 0] > 0 and k[1, 1] > 0):
        raise _fail(where, f"{key} focal lengths must be > 0, got fx={k[0, 0]}, fy={k[1, 1]}")
    if k[1, 0] != 0 or k[2].tolist() != [0.0, 0.0, 1.0]:
        raise _fail(where, f"{key} must be [fx s cx; 0 fy cy; 0 0 1], got {k.tolist()}")
    return k


def _check_rotation(value: Any, where: str, key: str) -> np.ndarray:
    """A rotation within :data:`ROTATION_TOLERANCE`; one further than 1e-6 from orthonormal (a
    matrix rounded in print) is replaced by the nearest rotation (U V^T of its SVD, as
    OpenCV's Rodrigues does), so that the rectifier's own 1e-6 check takes it."""
    r = _check_array(value, where, key, (3, 3))
    err = float(np.abs(r @ r.T - np.eye(3)).max())
    det = float(np.linalg.det(r))
    if err > ROTATION_TOLERANCE or abs(det - 1.0) > ROTATION_TOLERANCE:
        raise _fail(
            where,
            f"{key} must be a rotation (R R^T = I and det R = +1 within {ROTATION_TOLERANCE:g}), "
            f"got max |R R^T - I| = {err:.3g} and det R = {det:.9g}",
        )
    if err > _EXACT_ROTATION or abs(det - 1.0) > _EXACT_ROTATION:
        u, _, vt = np.linalg.svd(r)
        r = u @ vt
    return r


def _opencv_rational(d: np.ndarray, where: str, key: str) -> np.ndarray:
    """OpenCV's 12 and 14 coefficient forms (thin prism, tilt) of a plumb_bob distortion as
    its first 8 when the rest are 0, the rectifier's rule (rectify._rational_as_8);
    ValueError naming ``key`` when they are not; any other count unchanged."""
    from ..rectify import _RATIONAL_TERMS, _rational_as_8

    eight = _rational_as_8(d)
    if eight is None:
        raise _fail(where, f"{key} {_RATIONAL_TERMS.format(size=d.size)}")
    return eight


def _differ(a: float, b: float) -> bool:
    """Whether two values of a rectified pair that must be equal (the cameras' fx, fy, cy)
    differ by more than a calibration file's last printed digit: 1e-6 relative (1e-9 for
    zeros). The readers' and StereoCalibration.to_rig's one tolerance."""
    return abs(a - b) > 1e-6 * max(abs(a), abs(b)) + 1e-9


def _check_distortion(
    value: Any, model: str, where: str, key: str, named: str | None = None
) -> np.ndarray:
    """Distortion coefficients of ``model``; ``named`` the file's own name for the model,
    where it fixes the count (ROS's rational_polynomial 8, Kalibr's radtan 4). An empty list
    for the pinhole models is no distortion, five zeros (OpenCV's empty distCoeffs, ROS's
    empty D in image_geometry; the rectifier takes it so too); a fisheye model's zeros are
    not "no distortion", so it keeps its count. OpenCV's 12 and 14 coefficient forms are the
    first 8 when the rest are 0 (plumb_bob, no ``named``)."""
    d = _check_array(value, where, key, (-1,))
    if d.size == 0 and model == "plumb_bob":
        return np.zeros(5)
    if model == "plumb_bob" and named is None:
        # cv2.stereoCalibrate with CALIB_RATIONAL_MODEL returns (1, 14), which a
        # StereoCalibration built from its results refused while the OpenCV file reader
        # took it.
        d = _opencv_rational(d, where, key)
    name = named.strip().lower() if named is not None else model
    counts = _NAMED_COUNTS.get(name, DISTORTION_COUNTS[model])
    if d.size not in counts:
        takes = " or ".join(str(c) for c in counts)
        raise _fail(where, f"{key} has {d.size} coefficients; the {name} model takes {takes}")
    return d


def _check_model(value: Any, where: str, key: str) -> str:
    if not isinstance(value, str) or value.strip().lower() not in _MODEL_ALIASES:
        known = ", ".join(sorted(_MODEL_ALIASES))
        raise _fail(where, f"{key} must be one of {known}, got {_shown(value)}")
    return _MODEL_ALIASES[value.strip().lower()]


#: The largest image side a calibration may give: the rectifier's and remap's limit.
MAX_IMAGE_SIDE = 32000


def _check_image_size(value: Any, where: str, key: str) -> tuple[int, int]:
    if isinstance(value, np.ndarray):
        value = value.reshape(-1).tolist()
    if not isinstance(value, list | tuple) or len(value) != 2:
        raise _fail(where, f"{key} must be (width, height), got {_shown(value)}")
    w, h = value
    out = []
    for v in (w, h):
        f = _to_float(v)
        if f is None or not (f.is_integer() and f > 0):
            raise _fail(where, f"{key} must be two whole numbers > 0, got {_shown(value)}")
        out.append(int(f))
    if max(out) > MAX_IMAGE_SIDE:
        # The rectifier's limit, said here with the file and the key (it was "calib.image_size
        # must be at most 32000 x 32000 pixels", naming neither).
        raise _fail(
            where,
            f"{key} must be at most {MAX_IMAGE_SIDE} x {MAX_IMAGE_SIDE} pixels, got "
            f"{_shown(value)}",
        )
    return out[0], out[1]


def _to_float(v: Any) -> float | None:
    """A number from a parsed file: int or float (not bool), or a string that spells one
    (PyYAML leaves ``1e-05`` and OpenCV's ``.Nan`` as strings)."""
    if isinstance(v, bool | np.bool_):
        return None
    if isinstance(v, int | np.integer):
        # YAML and JSON integers have no size limit; float() raises OverflowError beyond a
        # double's range, where the value is as infinite as a double can say.
        try:
            return float(v)
        except OverflowError:
            return math.inf if v > 0 else -math.inf
    if isinstance(v, float | np.floating):
        return float(v)
    if isinstance(v, str):
        s = v.strip()
        if _NUMBER_RE.fullmatch(s):
            return float(s)
        special = {".nan": math.nan, ".inf": math.inf, "+.inf": math.inf, "-.inf": -math.inf}
        return special.get(s.lower())
    return None


#: The longest baseline, in metres, that a calibration read with no ``translation_unit`` may
#: have: OpenCV files do not record their unit, and a T in millimetres read as metres gives a
#: baseline (and every depth) 1000 times too large, so such a file is refused and the unit
#: must be given (``"m"`` accepts any length).
MAX_IMPLICIT_BASELINE_M = 10.0


def _check_implicit_baseline(
    length: float, translation_unit: str | None, where: str, what: str, convention: str
) -> None:
    """ValueError when no ``translation_unit`` was given and ``length`` (the baseline read as
    metres, from ``what``) exceeds :data:`MAX_IMPLICIT_BASELINE_M`: a file whose target was
    measured in millimetres (ROS's ``--square 108`` for 0.108 m, a Kalibr target yaml in mm)
    states metres by its ``convention`` but gives every depth 1000 times too large."""
    if translation_unit is None and length > MAX_IMPLICIT_BASELINE_M:
        raise _fail(
            where,
            f"{what} gives a baseline of {length:g}: read as metres ({convention}; no "
            f"translation unit given) that is an unlikely {length:g} m, far more likely a "
            "calibration target measured in millimetres; give the unit with "
            "translation_unit, e.g. 'mm', or 'm' to accept metres",
        )


def _unit(translation_unit: str | None) -> float:
    """Metres per unit; None (no unit given) is metres."""
    if translation_unit is None:
        return 1.0
    if translation_unit not in TRANSLATION_UNITS:
        known = ", ".join(repr(u) for u in TRANSLATION_UNITS)
        raise ValueError(f"translation_unit must be one of {known}, got {translation_unit!r}")
    return TRANSLATION_UNITS[translation_unit]


def _image_size_of(
    found: tuple[int, int] | None, given: Any, where: str, hint: str
) -> tuple[int, int]:
    """The image size from the file and/or the caller, which must agree when both are set."""
    if given is not None:
        # The caller's own argument: a wrong type is a TypeError (a file's wrong value, and
        # the caller's wrong numbers, stay ValueErrors naming the file or the parameter).
        items = given.reshape(-1).tolist() if isinstance(given, np.ndarray) else given
        if (
            not isinstance(items, list | tuple)
            or len(items) != 2
            or not all(
                isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
                for v in items
            )
        ):
            raise TypeError(
                f"image_size must be (width, height) as two numbers, got {_shown(given)}"
            )
        given = _check_image_size(given, "image_size", "image_size")
    if found is not None and given is not None and found != given:
        raise _fail(where, f"the file gives an image size of {found}, image_size= {given}")
    size = found or given
    if size is None:
        raise _fail(where, f"no image size in the file ({hint}): pass image_size=(width, height)")
    return size


def _check_cameras(cameras: Any, name: str = "cameras", kind: str = "") -> tuple[int, int]:
    """Two different camera numbers (integers >= 0, numpy's too): ValueError / TypeError
    naming ``name`` and the value; ``kind`` qualifies them in the message ("KITTI ")."""
    try:
        a, b = cameras
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be two camera numbers, got {cameras!r}") from None
    for c in (a, b):
        # numpy integers too (camera numbers read from an array); bool is not a number here.
        if isinstance(c, (bool, np.bool_)) or not isinstance(c, (int, np.integer)):
            raise TypeError(
                f"{name} must be two whole numbers >= 0, got {cameras!r} (a {type(c).__name__})"
            )
        if c < 0:
            raise ValueError(f"{name} must be two whole numbers >= 0, got {cameras!r}")
    a, b = int(a), int(b)
    if a == b:
        raise ValueError(f"{name} must be two different {kind}cameras, got {cameras!r}")
    return a, b
