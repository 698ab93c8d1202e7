"""The web page's depth-map view: a stereo pair in, disparity, depth and a point cloud out.

``POST /api/depthmap`` takes one JSON object:

- ``left``, ``right``: the images as base64 (a ``data:`` URL is accepted), PNG or JPEG (a
  JPEG with more images after it, MPO, as phones and stereo cameras write: its first), 8-bit
  grey or colour or 16-bit grey (an alpha channel must be opaque and is dropped; 16-bit
  colour, and 16-bit grey with alpha, are rejected); or, without them, ``"sample": true``
  for the package's synthetic pair (:mod:`stereodepth.sample`);
- ``rig``: the calculator's rig with its names and units (``baseline_mm`` and ``focal_px``
  with ``doffs_px``, or ``focal_mm`` and ``pixel_um``);
- ``method`` (``bm``, or ``sgm`` where the library has it), ``num_disparities`` (default: an
  eighth of the width rounded up to 16), ``block_size``, ``cost`` and ``disparity_step_px``
  (for the depth resolution);
- ``cx_px``, ``cy_px``: the left camera's principal point for the 3-D points (default: the
  image centre; the page sends those of an uploaded calib.txt), each at most 1e6 px in
  magnitude (beyond, the points' x and y could overflow float32).
- ``calib_size``: ``[width, height]`` of the images an uploaded calib.txt describes (the page
  sends its ``width`` and ``height``); the pair must have that size, as ``stereodepth match``
  requires, since a calibration of another resolution would scale every depth.

Numbers may come as JSON numbers or as numeric strings (what the page's form fields hold);
an integer field also takes a float with an integral value (``16.0``); null is the same as a
field not given. A field not named here, in the request or in ``rig`` (a misspelt
``doffs``), answers 422 at that field, and so does a key given twice in one object (JSON
would keep the last one). ``POST /api/calib`` takes ``{"calib": "<text of calib.txt>"}``
alone, with the same rules.

The answer has the summary (size, density, time, ranges), the images as PNG data URLs (the
left image, the colourised disparity and depth), the colour bars (limits and the colour table),
the raw float32 disparity, depth and confidence maps (base64, little-endian, row-major: the
page reads the exact values, so the depth it shows at a pixel is ``disparity_to_depth`` of
that pixel's disparity to the last digit), a decimated coloured point cloud, and download
links. ``GET /api/depthmap/{id}/point?x=&y=`` gives one pixel's numbers (its 3-D point from
:func:`stereodepth.reproject`); ``GET /api/depthmap/{id}/{file}`` the downloads. A query
parameter a route does not have (each but the point query has none), or x or y given twice,
answers 422 at it, as ``/api/calc`` does.

Limits and safety: each image at most ``max_upload_bytes`` (default 20 MB) and
``max_pixels`` (default 4 MP; both settable with ``create_app`` and ``stereodepth serve``);
the request body is read up to what two such images need and no further (413 beyond). Images
are decoded in memory and results kept in memory (the last few, under a random id); downloads
are written to a temporary folder of the server's choosing. Matching runs in worker threads
(at most two at once) so the server keeps answering. Every bad input answers 422 with
``{"detail": [{"loc": ["body", field], "msg": ..., "type": ...}]}`` at its field, whose
message names the field and what it got (a long value cut to about 40 characters), an
unknown result id or download 404 at ``["path", "key"]`` or ``["path", "name"]``, a body
too large 413, a body not sent as ``application/json`` 415 (a form or text/plain POST is one
any web site can make a browser send to this server), a missing extra (Pillow, matplotlib)
503 with the install hint; none 500. A client that closes the connection before it has sent
the whole body is dropped without an answer or a logged error.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import math
import re
import secrets
import struct
import sys
import tempfile
import threading
import warnings
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse, Response

from ..io import _bomb_pixels, upright

__all__ = ["DEFAULT_MAX_PIXELS", "DEFAULT_MAX_UPLOAD_BYTES", "DepthMapLimits", "make_router"]

#: Default limit of one uploaded image file, in bytes (20 MB).
DEFAULT_MAX_UPLOAD_BYTES = 20_000_000
#: Default limit of one image's size, in pixels (4 MP: 2560 x 1600 fits).
DEFAULT_MAX_PIXELS = 4_000_000
#: Results kept for the pixel queries and downloads (the oldest goes first).
KEPT_RESULTS = 6
#: Matching jobs running at once; more wait their turn (each uses every core).
CONCURRENT_JOBS = 2
#: The point cloud sent to the page has at most about this many points.
MAX_CLOUD_POINTS = 40_000
_FORMATS = ("PNG", "JPEG")
_BODY_SLACK = 1_000_000  # the JSON around the two images


@dataclass(frozen=True)
class DepthMapLimits:
    """The upload limits: bytes per image file and pixels per image."""

    max_upload_bytes: int = DEFAULT_MAX_UPLOAD_BYTES
    max_pixels: int = DEFAULT_MAX_PIXELS

    def __post_init__(self) -> None:
        from .. import _validate as check

        for name in ("max_upload_bytes", "max_pixels"):
            # numpy integers too (a limit from a config array was refused as 'must be an
            # integer >= 1, got np.int64(5)'); TypeError for a float or bool, as elsewhere.
            object.__setattr__(self, name, check.integer(name, getattr(self, name), minimum=1))

    @property
    def max_body_bytes(self) -> int:
        return 2 * (4 * math.ceil(self.max_upload_bytes / 3)) + _BODY_SLACK


class BadInput(Exception):
    """A bad field: answered 422 at ``loc``."""

    def __init__(self, loc: list[str], msg: str, kind: str = "value_error") -> None:
        super().__init__(msg)
        self.loc = loc
        self.msg = msg
        self.kind = kind


def _error_response(errors: list[BadInput], status: int = 422) -> JSONResponse:
    return JSONResponse(
        status_code=status,
        content={"detail": [{"loc": e.loc, "msg": e.msg, "type": e.kind} for e in errors]},
    )


def _mb(n: float) -> str:
    return f"{n / 1e6:.3g} MB"


def _mp(n: float) -> str:
    return f"{n / 1e6:.3g} MP"


def _shown(value: Any) -> str:
    """A received JSON value for a message: true, false and null as JSON writes them, a
    string or list as Python's repr, each cut to about 40 characters (a JSON integer has no
    size limit: one of 400 digits was shown whole)."""
    if value is None or isinstance(value, bool):
        return json.dumps(value)
    if isinstance(value, int):
        digits = str(value)
        return digits if len(digits) <= 40 else f"{digits[:20]}... ({len(digits)} digits)"
    if isinstance(value, str) and len(value) > 40:
        return repr(value[:40] + "...")
    try:
        text = repr(value)
    except RecursionError:  # an array nested thousands deep
        text = f"a {'list' if isinstance(value, list) else 'object'} nested too deeply"
    return text if len(text) <= 40 else text[:40] + "..."


def _json_kind(value: Any) -> str:
    """What a JSON value is, in JSON's words: an array, a string, a number, ..."""
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, str):
        return "a string"
    if value is None or isinstance(value, bool):
        return json.dumps(value)
    return f"the number {_shown(value)}"


# --- decoding an upload -----------------------------------------------------------------------
def _png_colour_bits(data: bytes) -> tuple[int, int] | None:
    """(bit depth, colour type) from a PNG's IHDR, or None."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 26 and data[12:16] == b"IHDR":
        return data[24], data[25]
    return None


_SIGNATURES = {b"\x89PNG\r\n\x1a\n": "PNG", b"\xff\xd8\xff": "JPEG"}
# Netpbm's kinds, which Pillow all calls PPM, by their magic number.
_NETPBM = {b"P1": "PBM", b"P4": "PBM", b"P2": "PGM", b"P5": "PGM", b"P3": "PPM", b"P6": "PPM"}
_PFM_HEAD = re.compile(rb"P[Ff]\s+(\d+)\s+(\d+)\s")
# JPEG's frame headers (SOF0 to SOF15 but DHT, JPG and DAC), which hold the image's size.
_JPEG_FRAMES = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def _header_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) as a PNG's IHDR or a JPEG's frame header gives it, or None: read before
    Pillow opens the file, whose decompression-bomb check names no size."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24 and data[12:16] == b"IHDR":
        w, h = struct.unpack(">II", data[16:24])
        return w, h
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    while i + 4 <= len(data) and data[i] == 0xFF:
        marker = data[i + 1]
        if marker == 0xFF:  # a fill byte
            i += 1
        elif marker == 0x01 or 0xD0 <= marker <= 0xD7:  # no length
            i += 2
        elif marker in _JPEG_FRAMES:
            if i + 9 > len(data):
                return None
            h, w = struct.unpack(">HH", data[i + 5 : i + 9])
            return w, h
        elif marker in (0xD9, 0xDA):  # the end, or the scan, before any frame header
            return None
        else:
            i += 2 + struct.unpack(">H", data[i + 2 : i + 4])[0]
    return None


def _received(data: bytes) -> str:
    """What an upload is, for a message: a PNG or JPEG file of n bytes (with its size in px
    when its header gives it), text (its beginning), or other bytes (their first, in hex)."""
    n = len(data)
    for signature, kind in _SIGNATURES.items():
        if data.startswith(signature):
            size = _header_size(data)
            px = f" ({size[0]}x{size[1]} px by its header)" if size is not None else ""
            return f"a {kind} file of {n} bytes{px}"
    head = data[:24]
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        text = ""
    if text and text.isprintable():
        return f"{n} bytes of text beginning {text!r}"
    return f"{n} bytes beginning {data[:8].hex(' ')}"


def _unreadable(field: str, data: bytes) -> str:
    """The message for a file Pillow cannot open, with what it got: a PNG or JPEG cut short
    (its first bytes are one's), text, or other bytes (their first, in hex)."""
    if any(data.startswith(signature) for signature in _SIGNATURES):
        return (
            f"{field}: the image is truncated or damaged: {_received(data)} that Pillow cannot read"
        )
    return f"{field}: not an image Pillow can read; give a PNG or JPEG file, got {_received(data)}"


def _pfm(field: str, data: bytes) -> str | None:
    """The message for a PFM file (Pillow calls one PPM, or cannot read it), else None."""
    head = _PFM_HEAD.match(data[:64])
    if head is None:
        return None
    w, h = int(head[1]), int(head[2])
    return (
        f"{field}: must be a PNG or JPEG image, got PFM ({w}x{h} px, {len(data)} bytes): PFM "
        "holds floating-point maps, such as the disparity.pfm this page and `stereodepth "
        "match` write, not an image to match"
    )


def _too_many_pixels(field: str, w: int, h: int, limits: DepthMapLimits) -> BadInput:
    return BadInput(
        ["body", field],
        f"{field}: the image is {w}x{h} px ({_mp(w * h)}), more than the limit of "
        f"{_mp(limits.max_pixels)}",
        "too_large",
    )


def _bomb(field: str, data: bytes, size: tuple[int, int] | None, exc: Exception) -> BadInput:
    """Pillow's decompression-bomb refusal, with the image's size: ``size``, from the header
    of a PNG or JPEG, else Pillow's count of pixels ("Image size (N pixels) exceeds limit
    ...")."""
    from PIL import Image

    count = _bomb_pixels(exc)
    if size is not None:
        got = f"the image is {size[0]}x{size[1]} px ({_mp(size[0] * size[1])})"
    elif count is not None:
        got = f"the image has {count} pixels ({_mp(count)})"
    else:
        got = f"the image ({_received(data)}) has too many pixels ({exc})"
    pillow = f"more than Pillow opens safely, {_mp(Image.MAX_IMAGE_PIXELS or 0)}"
    return BadInput(["body", field], f"{field}: {got}, {pillow}", "too_large")


def decode_image(field: str, data: bytes, limits: DepthMapLimits) -> np.ndarray:
    """An uploaded PNG or JPEG as (H, W) uint8/uint16 grey or (H, W, 3) uint8 RGB; BadInput
    at ``field`` for anything else, whose message says what the file is."""
    from PIL import Image, UnidentifiedImageError

    loc = ["body", field]
    if not data:
        raise BadInput(loc, f"{field}: the file is empty (0 bytes); choose an image file")
    if len(data) > limits.max_upload_bytes:
        raise BadInput(
            loc,
            f"{field}: the file is {_mb(len(data))}, more than the limit of "
            f"{_mb(limits.max_upload_bytes)}",
            "too_large",
        )
    if (pfm := _pfm(field, data)) is not None:
        raise BadInput(loc, pfm)
    size = _header_size(data)
    bits = _png_colour_bits(data)
    if bits is not None and bits[0] == 16 and bits[1] in (2, 4, 6):  # Pillow: the high byte
        kind = "grey and alpha" if bits[1] == 4 else "colour"
        w, h = size or (0, 0)
        raise BadInput(
            loc,
            f"{field}: 16-bit {kind} PNGs are not supported, got one of {w}x{h} px; give 8-bit "
            "colour or 16-bit grey",
        )
    # Beyond the limit by its header: refused before Pillow reads more (and before its
    # decompression-bomb check, which names no size, refuses a larger one).
    if size is not None and size[0] * size[1] > limits.max_pixels:
        raise _too_many_pixels(field, *size, limits)
    with warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        try:
            im = Image.open(io.BytesIO(data))
        except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
            raise _bomb(field, data, size, exc) from None
        except UnidentifiedImageError:
            raise BadInput(loc, _unreadable(field, data)) from None
        except (OSError, ValueError, SyntaxError) as exc:
            raise BadInput(
                loc, f"{field}: not a readable image, got {_received(data)} ({exc})"
            ) from None
    with im:
        w, h = im.size
        # MPO: a JPEG followed by more images (a phone photo's gain or depth map, a stereo
        # camera's second view); Pillow reads its first, the photo browsers show.
        if im.format not in _FORMATS and im.format != "MPO":
            kind = _NETPBM.get(data[:2], "PPM") if im.format == "PPM" else str(im.format)
            raise BadInput(
                loc,
                f"{field}: must be a PNG or JPEG image, got {kind} ({w}x{h} px, {len(data)} bytes)",
            )
        if w * h > limits.max_pixels:
            raise _too_many_pixels(field, w, h, limits)
        try:
            im.load()
        except (OSError, ValueError, SyntaxError) as exc:
            raise BadInput(
                loc,
                f"{field}: the image is truncated or damaged: a {w}x{h} px {im.format} file of "
                f"{len(data)} bytes that Pillow cannot decode ({exc})",
            ) from None
        im = upright(im)  # as the browser shows the file and read_image reads it
        mode = im.mode

        def refuse_transparent(alpha: np.ndarray) -> None:
            if (alpha != 255).any():
                raise BadInput(
                    loc,
                    f"{field}: the image has transparent pixels (an alpha channel): "
                    f"{int((alpha != 255).sum())} of its {w}x{h} px are not opaque; give an "
                    "opaque image",
                )

        key = im.info.get("transparency")
        if mode in ("I;16", "I;16B", "I;16L", "I", "L", "1") and isinstance(key, int):
            # A grey PNG's transparency chunk (one grey level, transparent) was taken as
            # opaque, where an RGB PNG's was refused; converting a 16-bit one to RGBA drops it.
            refuse_transparent(np.where(np.asarray(im) == key, 0, 255))
        if mode in ("I;16", "I;16B", "I;16L"):
            return np.asarray(im, dtype=np.uint16)
        if mode == "I":
            a = np.asarray(im)
            if a.min() < 0 or a.max() > 65535:
                raise BadInput(
                    loc,
                    f"{field}: 32-bit images are not supported, got a {w}x{h} px {im.format} of "
                    f"values from {a.min()} to {a.max()}; give 16-bit grey (0 to 65535)",
                )
            return a.astype(np.uint16)
        if mode in ("L", "1"):
            return np.asarray(im.convert("L"), dtype=np.uint8)
        if mode in ("RGBA", "LA", "PA", "P") or "transparency" in im.info:
            rgba = im.convert("RGBA")
            refuse_transparent(np.asarray(rgba)[..., 3])
            rgb = np.asarray(rgba.convert("RGB"), dtype=np.uint8)
            if (
                mode in ("LA", "P", "PA")
                and (rgb[..., 0] == rgb[..., 1]).all()
                and (rgb[..., 1] == rgb[..., 2]).all()
            ):
                return np.ascontiguousarray(rgb[..., 0])
            return rgb
        if mode in ("RGB", "CMYK", "YCbCr"):
            return np.asarray(im.convert("RGB"), dtype=np.uint8)
        raise BadInput(
            loc,
            f"{field}: images of mode {mode} are not supported, got a {w}x{h} px {im.format} of "
            "that mode; give 8-bit grey or colour, or 16-bit grey",
        )


def _b64(field: str, value: Any) -> bytes:
    loc = ["body", field]
    if not isinstance(value, str):
        raise BadInput(
            loc,
            f"{field} must be the image file as base64 text (or a data: URL), got "
            f"{_json_kind(value)}",
        )
    text = value
    if text.startswith("data:"):
        head, sep, text = text.partition(",")
        if not sep or ";base64" not in head:
            raise BadInput(
                loc,
                f"{field}: a data URL must be base64 (data:<type>;base64,<data>), got "
                f"{_shown(head if sep else value)}",
            )
    if any(c in text for c in " \t\r\n"):
        # MIME base64 (RFC 2045; GNU base64, openssl) wraps its lines: the breaks carry nothing.
        text = "".join(text.split())
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise BadInput(loc, f"{field}: not valid base64, {_not_base64(text)}") from None


_BASE64 = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/")


def _not_base64(text: str) -> str:
    """What is wrong with text that base64 refused: its first character that base64 does not
    have, else its length or padding."""
    body = text.rstrip("=")
    for i, c in enumerate(body):
        if c not in _BASE64:
            return (
                f"got {c!r} at character {i + 1} (base64 has A-Z, a-z, 0-9, + and /, and = at "
                "the end)"
            )
    return (
        f"got {len(text)} characters ({len(text) - len(body)} of them = at the end): the text "
        "is cut short or its = padding is wrong"
    )


# --- the request --------------------------------------------------------------------------------
@dataclass
class Job:
    left: np.ndarray
    right: np.ndarray
    sample: bool
    rig: Any  # StereoRig
    method: str
    num_disparities: int | None
    block_size: int | None
    cost: str | None
    disparity_step_px: float
    truth: np.ndarray | None = None  # the sample pair's true disparity
    cx_px: float | None = None  # the left camera's principal point; None: the image centre
    cy_px: float | None = None


_RIG_NAMES = ("baseline_mm", "focal_mm", "pixel_um", "focal_px", "doffs_px")
#: The fields of the request (any other is refused: a misspelt one was ignored silently).
_BODY_NAMES = (
    "left",
    "right",
    "sample",
    "rig",
    "method",
    "num_disparities",
    "block_size",
    "cost",
    "disparity_step_px",
    "cx_px",
    "cy_px",
    "calib_size",
)


def _unknown(loc: list[str], what: str, given: dict[str, Any], known: tuple[str, ...]) -> list[Any]:
    """BadInput for each key of ``given`` not in ``known``."""
    return [
        BadInput(
            [*loc, str(k)[:40]],
            f"{str(k)[:40]} is not a field of {what}, got {_shown(v)} (its fields: "
            f"{', '.join(known)})",
            "extra_forbidden",
        )
        for k, v in given.items()
        if k not in known
    ]


#: The largest magnitude of cx_px / cy_px (px): a principal point is near the image.
MAX_PRINCIPAL_POINT_PX = 1e6


def _number(loc: list[str], name: str, value: Any, rule_text: str) -> float | None:
    if value is None or (isinstance(value, str) and value.strip() == ""):
        return None
    if isinstance(value, bool):
        raise BadInput(loc, f"{name} must be {rule_text}, got {_shown(value)}")
    if isinstance(value, str):
        try:
            v = float(value)
        except ValueError:
            raise BadInput(loc, f"{name} must be {rule_text}, got {_shown(value)}") from None
    elif isinstance(value, float):
        v = value
    elif isinstance(value, int):
        # JSON integers have no size limit: one beyond a double's range is out of every
        # field's range (float() would raise OverflowError, a 500), not a number to use.
        try:
            v = float(value)
        except OverflowError:
            v = math.inf if value > 0 else -math.inf
    else:
        raise BadInput(loc, f"{name} must be {rule_text}, got {_shown(value)}")
    return v


def _rig_of(body: dict[str, Any]) -> Any:
    from .._calib_rule import rig_range_problem
    from .app import FIELDS, _library_error, _rig

    raw = body.get("rig")
    if raw is None:
        raise BadInput(
            ["body", "rig"],
            "rig is required: an object with baseline_mm, and focal_px (and doffs_px) or "
            "focal_mm and pixel_um",
            "missing",
        )
    if not isinstance(raw, dict):
        raise BadInput(
            ["body", "rig"],
            f"rig must be an object with the calculator's fields ({', '.join(_RIG_NAMES)}), "
            f"got {_json_kind(raw)}",
        )
    values: dict[str, float | None] = {}
    errors: list[BadInput] = _unknown(["body", "rig"], "rig", raw, _RIG_NAMES)
    for name in _RIG_NAMES:
        f = FIELDS[name]
        loc = ["body", "rig", name]
        try:
            v = _number(loc, name, raw.get(name), f.rule)
        except BadInput as e:
            errors.append(e)
            continue
        if v is not None:
            ok = math.isfinite(v)
            if ok and f.minimum is not None:
                ok = v > f.minimum if f.exclusive_minimum else v >= f.minimum
            if ok and f.maximum is not None:
                ok = v <= f.maximum
            if not ok:
                errors.append(
                    BadInput(loc, f"{name} must be {f.rule}, got {_shown(raw.get(name))}")
                )
                continue
        values[name] = v
    if errors:
        raise ExceptionGroupLike(errors)
    if values.get("baseline_mm") is None:
        raise BadInput(["body", "rig", "baseline_mm"], "baseline_mm is required", "missing")
    try:
        rig = _rig(
            float(values["baseline_mm"] or 0),
            values.get("focal_mm"),
            values.get("pixel_um"),
            values.get("focal_px"),
            values.get("doffs_px"),
            None,
            None,
        )
    except (ValueError, TypeError, ArithmeticError) as exc:
        # The library's message begins with the parameter ("baseline_mm=1e-300 with ...").
        found = _library_error(exc, {})
        raise BadInput(["body", "rig", *found["loc"][1:]], found["msg"]) from None
    if isinstance(rig, list):
        raise ExceptionGroupLike(
            [BadInput(["body", "rig", e["loc"][-1]], e["msg"], e["type"]) for e in rig]
        )
    # The depth map is float32: B*f beyond its range was answered at the body with the
    # library's message, which names its own parameters and suggests float64 input.
    problem = rig_range_problem(float(rig.focal_px), rig.baseline_mm / 1000.0, rig.doffs_px)
    if problem is not None:
        raise BadInput(["body", "rig"], f"rig: {problem}")
    return rig


class ExceptionGroupLike(Exception):
    """Several bad fields at once."""

    def __init__(self, errors: list[BadInput]) -> None:
        super().__init__("; ".join(e.msg for e in errors))
        self.errors = errors


def _int_field(body: dict[str, Any], name: str, lo: int, hi: int) -> int | None:
    value = body.get(name)
    if value is None or (isinstance(value, str) and value.strip() == ""):
        return None
    rule = f"an integer from {lo} to {hi}"
    loc = ["body", name]
    v: Any = value
    if isinstance(value, str):
        try:
            v = int(value.strip())
        except ValueError:
            raise BadInput(loc, f"{name} must be {rule}, got {_shown(value)}") from None
    if isinstance(v, float) and v.is_integer():
        v = int(v)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise BadInput(loc, f"{name} must be {rule}, got {_shown(value)}")
    return v


class _RepeatedKey(ValueError):
    def __init__(self, key: str, values: list[Any]) -> None:
        super().__init__(key)
        self.key, self.values = key, values


def _no_repeated_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """json's object_pairs_hook: an object, refusing a key given twice (json keeps the last
    one without a word, so {"num_disparities": 16, "num_disparities": 64} searched 64)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _RepeatedKey(key, [out[key], value])
        out[key] = value
    return out


def _load_json(data: bytes) -> Any:
    """The request's JSON; BadInput for text that is not JSON, nested too deeply, or with an
    object key given twice (at that key, where it is a field of the request or of rig)."""
    try:
        return json.loads(data, object_pairs_hook=_no_repeated_keys)
    except _RepeatedKey as exc:
        shown = ", ".join(repr(v)[:40] for v in exc.values)
        key = str(exc.key)[:40]
        raise BadInput(
            ["body", "rig", key] if key in _RIG_NAMES else ["body", key],
            f"{key} is given twice ({shown}): give it once",
            "repeated",
        ) from None
    except UnicodeDecodeError as exc:
        raise BadInput(
            ["body"],
            f"the request must be JSON in UTF-8, got byte 0x{exc.object[exc.start]:02x} at "
            f"position {exc.start}",
        ) from None
    except json.JSONDecodeError as exc:
        got = (
            "an empty body"
            if not data.strip()
            else f"text that is not: {exc.msg} at line {exc.lineno} column {exc.colno}"
        )
        raise BadInput(["body"], f"the request must be JSON, got {got}") from None
    except ValueError:  # an integer of more digits than Python converts (3.10.7 on)
        limit = getattr(sys, "get_int_max_str_digits", lambda: 4300)()
        raise BadInput(
            ["body"],
            f"the request must be JSON whose integers have at most {limit} digits, got one "
            "with more",
        ) from None
    except RecursionError:  # arrays or objects nested thousands deep
        raise BadInput(["body"], "the request must be JSON nested less deeply") from None


def _parse_request(data: bytes, limits: DepthMapLimits) -> Job:
    return parse_job(_load_json(data), limits)


def parse_job(body: Any, limits: DepthMapLimits) -> Job:
    """The checked request, or BadInput / ExceptionGroupLike naming the fields."""
    from ..match_pair import METHODS, prepare_pair, sgm_available
    from ..matching import MAX_BLOCK_SIZE, MAX_NUM_DISPARITIES

    if not isinstance(body, dict):
        raise BadInput(["body"], f"the request must be a JSON object, got {_json_kind(body)}")
    errors: list[BadInput] = _unknown(["body"], "/api/depthmap", body, _BODY_NAMES)
    try:
        rig = _rig_of(body)
    except BadInput as e:
        errors.append(e)
    except ExceptionGroupLike as g:
        errors.extend(g.errors)

    method = body.get("method")
    if method is None:  # null: the default, as for the other fields
        method = "bm"
    if method not in METHODS:
        errors.append(
            BadInput(["body", "method"], f"method must be bm or sgm, got {_shown(method)}")
        )
    elif method == "sgm" and not sgm_available():
        errors.append(
            BadInput(
                ["body", "method"],
                "method sgm (semi-global matching) is not in this version of the library; use bm",
            )
        )
    cost = body.get("cost")
    if cost is not None and (not isinstance(cost, str) or cost not in MAX_BLOCK_SIZE):
        errors.append(BadInput(["body", "cost"], f"cost must be census or sad, got {_shown(cost)}"))
    nums: dict[str, int | None] = {}
    for name, lo, hi in (
        ("num_disparities", 1, MAX_NUM_DISPARITIES),
        # 1 for semi-global matching's pixel-wise cost; each matcher checks its own sizes.
        ("block_size", 1, max(MAX_BLOCK_SIZE.values())),
    ):
        try:
            nums[name] = _int_field(body, name, lo, hi)
        except BadInput as e:
            errors.append(e)
    step = 1.0
    try:
        got = _number(
            ["body", "disparity_step_px"],
            "disparity_step_px",
            body.get("disparity_step_px"),
            "a number > 0 and <= 1000",
        )
        if got is not None:
            if not (math.isfinite(got) and 0 < got <= 1000):
                raise BadInput(
                    ["body", "disparity_step_px"],
                    f"disparity_step_px must be a number > 0 and <= 1000, got "
                    f"{_shown(body.get('disparity_step_px'))}",
                )
            step = got
    except BadInput as e:
        errors.append(e)

    centre: dict[str, float | None] = {}
    for name in ("cx_px", "cy_px"):
        rule = f"a finite number (px) of magnitude at most {MAX_PRINCIPAL_POINT_PX:g}"
        try:
            v = _number(["body", name], name, body.get(name), rule)
            if v is not None and not (math.isfinite(v) and abs(v) <= MAX_PRINCIPAL_POINT_PX):
                raise BadInput(["body", name], f"{name} must be {rule}, got {_shown(body[name])}")
            centre[name] = v
        except BadInput as e:
            errors.append(e)

    calib_size: tuple[int, int] | None = None
    if body.get("calib_size") is not None:
        size = body["calib_size"]
        if (
            not isinstance(size, list)
            or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)
        ):
            errors.append(
                BadInput(
                    ["body", "calib_size"],
                    f"calib_size must be [width, height], two integers > 0, got {_shown(size)}",
                )
            )
        else:
            calib_size = (size[0], size[1])

    sample = body.get("sample")
    if sample is None:  # null: the default, as for the other fields
        sample = False
    if not isinstance(sample, bool):
        errors.append(
            BadInput(["body", "sample"], f"sample must be true or false, got {_shown(sample)}")
        )
        sample = False
    left = right = None
    truth = None
    if sample:
        from ..sample import sample_pair

        errors.extend(  # else they were ignored: the answer was the sample's
            BadInput(["body", f], f"{f}: give the images or sample: true, not both")
            for f in ("left", "right")
            if body.get(f) is not None
        )
        s = sample_pair()
        left, right, truth = s.left, s.right, s.disparity
    else:
        images: dict[str, np.ndarray] = {}
        files: dict[str, bytes] = {}
        for field in ("left", "right"):
            if body.get(field) is None:
                errors.append(
                    BadInput(
                        ["body", field],
                        f"{field} is required: choose an image file (or sample: true)",
                        "missing",
                    )
                )
                continue
            try:
                files[field] = _b64(field, body[field])
                # Every disparity 0, every depth unknown: `stereodepth match` refuses it too.
                # Only of a left image that decoded: else right's own problem is named (two
                # empty files were "the same file as left", not empty).
                if field == "right" and "left" in images and files[field] == files["left"]:
                    raise BadInput(
                        ["body", "right"],
                        f"right: the same file as left, byte for byte ({_received(files[field])}); "
                        "choose the other image",
                    )
                images[field] = decode_image(field, files[field], limits)
            except BadInput as e:
                errors.append(e)
        if len(images) == 2:
            try:
                prepare_pair(images["left"], images["right"])  # the checks only
                left, right = images["left"], images["right"]
            except ValueError as exc:
                errors.append(BadInput(["body", "right"], str(exc)))
    # The sample pair too: a calib_size beside sample: true was ignored without a word.
    if calib_size is not None and left is not None:
        h, w = left.shape[:2]
        if calib_size != (w, h):
            errors.append(
                BadInput(
                    ["body", "calib"],
                    f"calib: the calib.txt is for {calib_size[0]}\u00d7{calib_size[1]} px "
                    f"images, the pair is {w}\u00d7{h} px (a calibration of another "
                    "resolution would scale every depth): use the calib.txt of these images",
                )
            )
    if errors:
        raise ExceptionGroupLike(errors)
    assert left is not None and right is not None
    return Job(
        left=left,
        right=right,
        sample=sample,
        rig=rig,
        method=method,
        num_disparities=nums.get("num_disparities"),
        block_size=nums.get("block_size"),
        cost=cost,
        disparity_step_px=step,
        truth=truth,
        cx_px=centre.get("cx_px"),
        cy_px=centre.get("cy_px"),
    )


# --- the computation ---------------------------------------------------------------------------
@dataclass
class Stored:
    """A result kept for pixel queries and downloads."""

    disparity: np.ndarray
    depth: np.ndarray
    confidence: np.ndarray | None
    colours: np.ndarray
    focal_px: float
    baseline_m: float
    doffs_px: float
    cx_px: float
    cy_px: float

    def points(self, rows: int | None = None) -> np.ndarray:
        """reproject of the disparity (its first ``rows`` rows) with the rig."""
        from ..pointcloud import reproject

        d = self.disparity if rows is None else self.disparity[:rows]
        return reproject(
            d,
            focal_px=self.focal_px,
            baseline_m=self.baseline_m,
            doffs_px=self.doffs_px,
            cx_px=self.cx_px,
            cy_px=self.cy_px,
        )


def _display(image: np.ndarray) -> np.ndarray:
    """An image as 8-bit for the page and the points' colours: 16-bit grey stretched from its
    min..max as the matchers stretch it (:func:`stereodepth.colormap.to_uint8`)."""
    from ..colormap import to_uint8

    return to_uint8(image)


def _data_url(rgb: np.ndarray) -> str:
    from ..colormap import png_bytes

    return "data:image/png;base64," + base64.b64encode(png_bytes(rgb, compress_level=1)).decode()


def _f32(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype="<f4").tobytes()).decode("ascii")


def _colorbar(values: np.ndarray, unit: str) -> dict[str, Any]:
    from ..colormap import colorize_limits, colormap_lut

    lo, hi = colorize_limits(values)
    lut = colormap_lut("turbo")
    return {
        "vmin": lo,
        "vmax": hi,
        "unit": unit,
        "colors": ["#{:02x}{:02x}{:02x}".format(*map(int, c)) for c in lut[::8]]
        + ["#{:02x}{:02x}{:02x}".format(*map(int, lut[-1]))],
    }


def _cloud(points: np.ndarray, colours: np.ndarray) -> dict[str, Any]:
    valid = np.isfinite(points).all(axis=-1)
    n = int(valid.sum())
    step = max(1, math.ceil(math.sqrt(n / MAX_CLOUD_POINTS))) if n else 1
    sub = points[::step, ::step]
    ok = valid[::step, ::step]
    c = colours[::step, ::step]
    if c.ndim == 2:
        c = np.repeat(c[..., None], 3, axis=-1)
    p = sub[ok].astype(np.float64)
    cols = c[ok]
    # 0.1 mm for a scene of a metre or more; finer for a smaller one, to 5 significant digits
    # of its largest coordinate (a rig of 1 mm baseline, a microscope's, had every point on a
    # 0.1 mm grid, and a smaller one all points at 0).
    extent = float(np.abs(p).max()) if p.size else 0.0
    decimals = 4 if not 0 < extent < 1 else 4 - math.floor(math.log10(extent))
    return {
        "step": step,
        "count": int(ok.sum()),
        "x": np.round(p[:, 0], decimals).tolist(),
        "y": np.round(p[:, 1], decimals).tolist(),
        "z": np.round(p[:, 2], decimals).tolist(),
        # The points' colours: base64 of uint8 R, G, B per point, in order.
        "rgb": base64.b64encode(np.ascontiguousarray(cols, dtype=np.uint8).tobytes()).decode(),
    }


def _against_truth(disparity: np.ndarray, truth: np.ndarray) -> dict[str, float | None]:
    """How the estimate compares with the true disparity (the sample pair): the mean absolute
    error and the fraction off by more than 1 px, over the pixels with an estimate."""
    ok = np.isfinite(disparity) & np.isfinite(truth)
    if not ok.any():
        return {"mean_abs_error_px": None, "bad_1": None}
    err = np.abs(disparity[ok].astype(np.float64) - truth[ok])
    return {"mean_abs_error_px": float(err.mean()), "bad_1": float((err > 1).mean())}


def compute(job: Job) -> tuple[dict[str, Any], Stored]:
    """Runs the matcher and builds the answer (in a worker thread)."""
    from ..match_pair import match_pair

    rig = job.rig
    focal_px = float(rig.focal_px)
    baseline_m = rig.baseline_mm / 1000.0
    doffs = float(rig.doffs_px)
    result = match_pair(
        job.left,
        job.right,
        method=job.method,
        num_disparities=job.num_disparities,
        block_size=job.block_size,
        cost=job.cost,
        focal_px=focal_px,
        baseline_m=baseline_m,
        doffs_px=doffs,
    )
    assert result.depth is not None
    colours = _display(job.left)
    from ..colormap import colorize

    h, w = result.disparity.shape
    stored = Stored(
        disparity=result.disparity,
        depth=result.depth,
        confidence=result.confidence,
        colours=colours,
        focal_px=focal_px,
        baseline_m=baseline_m,
        doffs_px=doffs,
        cx_px=(w - 1) / 2.0 if job.cx_px is None else job.cx_px,
        cy_px=(h - 1) / 2.0 if job.cy_px is None else job.cy_px,
    )
    points = stored.points()
    summary = result.summary()
    answer: dict[str, Any] = {
        **summary,
        "sample": job.sample,
        "rig": {
            "focal_px": focal_px,
            "baseline_mm": rig.baseline_mm,
            "doffs_px": doffs,
            "cx_px": stored.cx_px,
            "cy_px": stored.cy_px,
            # B (m) x f (px), as StereoRig computes it: the page's depth resolution is
            # Z * Z * step / bf_m_px, StereoRig.depth_resolution_m's formula.
            "bf_m_px": rig.baseline_mm / 1000.0 * rig.focal_px,
            "disparity_step_px": job.disparity_step_px,
        },
        "images": {
            "left": _data_url(colours),
            "disparity": _data_url(colorize(result.disparity)),
            "depth": _data_url(colorize(result.depth)),
        },
        "colorbars": {
            "disparity": _colorbar(result.disparity, "px"),
            "depth": _colorbar(result.depth, "m"),
        },
        "arrays": {
            "encoding": "base64 float32 little-endian, row-major (H, W); NaN where unknown",
            "disparity": _f32(result.disparity),
            "depth": _f32(result.depth),
            "confidence": None if result.confidence is None else _f32(result.confidence),
        },
        "points": _cloud(points, colours),
        "truth": None if job.truth is None else _against_truth(result.disparity, job.truth),
    }
    return answer, stored


# --- downloads ---------------------------------------------------------------------------------
DOWNLOADS = {
    "disparity.pfm": "application/octet-stream",
    "disparity.npy": "application/octet-stream",
    "depth.npy": "application/octet-stream",
    "depth.pfm": "application/octet-stream",
    "depth-mm.png": "image/png",
    "points.ply": "application/octet-stream",
}


def download_bytes(stored: Stored, name: str) -> bytes:
    """One download, written by the library's writers into a temporary folder."""
    from .. import io as sio
    from ..depth import disparity_to_depth
    from ..pointcloud import write_ply

    with tempfile.TemporaryDirectory(prefix="stereodepth-web-") as tmp:
        path = Path(tmp) / name
        if name == "disparity.pfm":
            sio.write_disparity_pfm(path, stored.disparity)  # Middlebury's: +inf holes
        elif name == "disparity.npy":
            sio.write_npy(path, stored.disparity)
        elif name == "depth.npy":
            sio.write_npy(path, stored.depth)
        elif name == "depth.pfm":
            sio.write_pfm(path, stored.depth)
        elif name == "depth-mm.png":
            mm = disparity_to_depth(
                stored.disparity,
                focal_px=stored.focal_px,
                baseline_m=stored.baseline_m,
                doffs_px=stored.doffs_px,
                dtype=np.uint16,
            )
            sio.write_png16(path, mm)
        else:
            pts = stored.points()
            write_ply(path, pts, stored.colours, comment="stereodepth web")
        return path.read_bytes()


# --- the routes --------------------------------------------------------------------------------
class _Results:
    """The last KEPT_RESULTS results by id, thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: OrderedDict[str, Stored] = OrderedDict()

    def add(self, stored: Stored) -> str:
        key = secrets.token_urlsafe(12)
        with self._lock:
            self._items[key] = stored
            while len(self._items) > KEPT_RESULTS:
                self._items.popitem(last=False)
        return key

    def get(self, key: str) -> Stored | None:
        with self._lock:
            return self._items.get(key)


def _not_json(request: Request) -> Response | None:
    """415 for a body that does not say it is JSON, else None. A form or text/plain POST is
    a request any web site may make a browser send without asking (no CORS preflight), so
    another site could have the local server match images; FastAPI refuses such bodies for
    its JSON parameters for this reason (CSRF), and these routes read the body themselves."""
    media = request.headers.get("content-type", "").split(";", 1)[0].strip().lower()
    if media == "application/json" or (
        media.startswith("application/") and media.endswith("+json")
    ):
        return None
    return _error_response(
        [
            BadInput(
                ["header", "content-type"],
                f"the request must be JSON sent as application/json, got content-type "
                f"{media[:60]!r}",
                "unsupported_media_type",
            )
        ],
        415,
    )


class _ClientGone(Exception):
    """The client closed the connection before it had sent the whole body."""


def _client_gone() -> Response:
    """The answer to a client that left mid-upload: nobody reads it (the server drops it),
    but the route ends as usual, without the traceback and 500 of ClientDisconnect."""
    return Response(status_code=400)


async def _read_body(request: Request, limit: int) -> bytes | None:
    """The body, or None when it is larger than ``limit`` (read no further than that);
    :class:`_ClientGone` when the client closes the connection before its end."""
    from starlette.requests import ClientDisconnect

    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        return None
    chunks: list[bytes] = []
    size = 0
    try:
        async for chunk in request.stream():
            size += len(chunk)
            if size > limit:
                return None
            chunks.append(chunk)
    except ClientDisconnect:
        raise _ClientGone from None
    return b"".join(chunks)


def _no_result(key: str) -> BadInput:
    return BadInput(
        ["path", "key"],
        f"key: no result {_shown(key)}; the server keeps the last {KEPT_RESULTS} depth maps "
        "(and none across a restart): compute it again",
    )


def make_router(limits: DepthMapLimits) -> APIRouter:
    """The depth view's routes, with these upload limits."""
    import anyio

    from .app import known_parameters

    router = APIRouter()
    add_calib_route(router)
    results = _Results()
    jobs = anyio.CapacityLimiter(CONCURRENT_JOBS)

    # Each route refuses a query parameter it does not have, as /api/calc does (the point
    # query ignored ?x=1&y=2&z=3, and the others any query, without a word).
    @router.get(
        "/api/depthmap/limits",
        summary="The upload limits and the sample pair's rig",
        dependencies=[Depends(known_parameters("/api/depthmap/limits"))],
    )
    def depthmap_limits() -> dict[str, Any]:
        from ..match_pair import sgm_available
        from ..matching import DEFAULT_BLOCK_SIZE
        from ..sample import SAMPLE_BASELINE_MM, SAMPLE_FOCAL_PX

        # Each method's own defaults, for the page's form: block matching's block size and
        # cost are not semi-global matching's (which takes no cost).
        defaults: dict[str, dict[str, Any]] = {
            "bm": {"block_size": DEFAULT_BLOCK_SIZE, "cost": "census"}
        }
        if sgm_available():
            from ..semi_global import DEFAULT_BLOCK_SIZE as SGM_BLOCK_SIZE

            defaults["sgm"] = {"block_size": SGM_BLOCK_SIZE, "cost": None}
        return {
            "max_upload_bytes": limits.max_upload_bytes,
            "max_pixels": limits.max_pixels,
            "formats": list(_FORMATS),
            "methods": list(defaults),
            "defaults": defaults,
            "sample": {
                "width_px": 320,
                "height_px": 240,
                "focal_px": SAMPLE_FOCAL_PX,
                "baseline_mm": SAMPLE_BASELINE_MM,
                "doffs_px": 0.0,
            },
        }

    @router.post(
        "/api/depthmap",
        summary="A stereo pair to disparity, depth and a point cloud (see the module's doc)",
        responses={422: {"description": "Bad input, at its field"}, 413: {}},
        dependencies=[Depends(known_parameters("/api/depthmap", body=True))],
    )
    async def depthmap(request: Request) -> Response:
        if (refused := _not_json(request)) is not None:
            return refused
        try:
            data = await _read_body(request, limits.max_body_bytes)
        except _ClientGone:
            return _client_gone()
        if data is None:
            return _error_response(
                [
                    BadInput(
                        ["body"],
                        f"the request is larger than {_mb(limits.max_body_bytes)}: each image "
                        f"may be at most {_mb(limits.max_upload_bytes)}",
                        "too_large",
                    )
                ],
                413,
            )
        try:
            # Parsing tens of megabytes of JSON and decoding the images: in a worker thread.
            job = await anyio.to_thread.run_sync(_parse_request, data, limits, limiter=jobs)
            answer, stored = await anyio.to_thread.run_sync(compute, job, limiter=jobs)
        except BadInput as e:
            return _error_response([e])
        except ExceptionGroupLike as g:
            return _error_response(g.errors)
        except ImportError as exc:  # an extra that is not installed: Pillow, matplotlib
            return _error_response([BadInput(["body"], str(exc), "missing_extra")], 503)
        except (ValueError, TypeError) as exc:  # the library's parameter checks
            msg = str(exc)
            name = msg.split(" ", 1)[0]
            field = name if name in ("num_disparities", "block_size", "cost") else None
            return _error_response([BadInput(["body", field] if field else ["body"], msg)])
        key = results.add(stored)
        answer["id"] = key
        answer["downloads"] = {n: f"/api/depthmap/{key}/{n}" for n in DOWNLOADS}
        return JSONResponse(answer)

    @router.get(
        "/api/depthmap/{key}/point",
        summary="One pixel's disparity, depth and 3-D point",
        description="x and y, each once; another parameter answers 422 at it.",
        # x or y twice: the last one was used without a word
        dependencies=[Depends(known_parameters("/api/depthmap/{key}/point", ("x", "y")))],
    )
    def point(key: str, x: int, y: int) -> Response:
        stored = results.get(key)
        if stored is None:
            return _error_response([_no_result(key)], 404)
        h, w = stored.disparity.shape
        bad = [
            BadInput(["query", n], f"{n} must be an integer from 0 to {m - 1}, got {v}")
            for n, v, m in (("x", x, w), ("y", y, h))
            if not 0 <= v < m
        ]
        if bad:
            return _error_response(bad)
        # The rows down to y, as reproject computes them for the whole map (same x, y, cx, cy).
        p = stored.points(rows=y + 1)[y, x]

        def num(v: Any) -> float | None:
            f = float(v)
            return f if math.isfinite(f) else None

        return JSONResponse(
            {
                "x": x,
                "y": y,
                "disparity_px": num(stored.disparity[y, x]),
                "depth_m": num(stored.depth[y, x]),
                "confidence": None if stored.confidence is None else num(stored.confidence[y, x]),
                "point_m": None if not np.isfinite(p).all() else [float(v) for v in p],
            }
        )

    @router.get(
        "/api/depthmap/{key}/{name}",
        summary="Downloads: disparity, depth, PLY",
        dependencies=[Depends(known_parameters("/api/depthmap/{key}/{name}"))],
    )
    def download(key: str, name: str) -> Response:
        stored = results.get(key)
        errors = [] if stored is not None else [_no_result(key)]
        if name not in DOWNLOADS:
            errors.append(
                BadInput(
                    ["path", "name"],
                    f"name must be one of {', '.join(DOWNLOADS)}, got {_shown(name)}",
                )
            )
        if errors or stored is None:
            return _error_response(errors, 404)
        return Response(
            download_bytes(stored, name),
            media_type=DOWNLOADS[name],
            headers={"Content-Disposition": f'attachment; filename="{name}"'},
        )

    return router


_CALIB_MAX_CHARS = 100_000
_CALIB_MAX_BODY = 200_000


def parse_calib(text: Any) -> dict[str, Any]:
    """A Middlebury calib.txt's rig for the page, or BadInput at ``calib``."""
    from ..calib import read_middlebury_calib

    loc = ["body", "calib"]
    if text is None:
        raise BadInput(loc, "calib is required: the text of a Middlebury calib.txt", "missing")
    if not isinstance(text, str) or not text.strip():
        got = _json_kind(text) if not isinstance(text, str) else "an empty text"
        raise BadInput(loc, f"calib must be the text of a Middlebury calib.txt, got {got}")
    if len(text) > _CALIB_MAX_CHARS:
        raise BadInput(
            loc,
            f"calib: a calib.txt is a few lines; this one is {len(text)} characters, more than "
            f"the limit of {_CALIB_MAX_CHARS}",
            "too_large",
        )
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:  # a lone surrogate ("\ud800" in the JSON): no text file
        raise BadInput(
            loc, f"calib: the text is not valid Unicode ({text[exc.start : exc.end]!r})"
        ) from None
    with tempfile.TemporaryDirectory(prefix="stereodepth-web-") as tmp:
        path = Path(tmp) / "calib.txt"
        path.write_text(text, encoding="utf-8")
        try:
            c = read_middlebury_calib(path)
        except (ValueError, OSError) as exc:
            raise BadInput(loc, "calib: " + str(exc).replace(str(path), "calib.txt")) from None
    return {
        "focal_px": c.focal_px,
        "baseline_mm": c.baseline_mm,
        "doffs_px": c.doffs_px,
        "width_px": c.width_px,
        "height_px": c.height_px,
        "ndisp": c.ndisp,
        "cx_px": float(c.cam0[0, 2]),
        "cy_px": float(c.cam0[1, 2]),
    }


def add_calib_route(router: APIRouter) -> None:
    """``POST /api/calib``: ``{"calib": "<text of calib.txt>"}`` to the rig's numbers."""
    from .app import known_parameters

    @router.post(
        "/api/calib",
        summary="A Middlebury calib.txt to the rig's numbers",
        dependencies=[Depends(known_parameters("/api/calib", body=True))],
    )
    async def calib(request: Request) -> Response:
        if (refused := _not_json(request)) is not None:
            return refused
        try:
            data = await _read_body(request, _CALIB_MAX_BODY)
        except _ClientGone:
            return _client_gone()
        if data is None:
            return _error_response(
                [
                    BadInput(
                        ["body", "calib"],
                        f"calib: the file is too large: the request is more than "
                        f"{_CALIB_MAX_BODY} bytes (a calib.txt is a few lines)",
                        "too_large",
                    )
                ],
                413,
            )
        try:
            body = _load_json(data)
        except BadInput as e:
            return _error_response([e])
        if not isinstance(body, dict):
            return _error_response(
                [BadInput(["body"], f"the request must be a JSON object, got {_json_kind(body)}")]
            )
        # A misspelt field ({"calib_txt": ...}) was ignored: the answer was "give the text".
        unknown = _unknown(["body"], "/api/calib", body, ("calib",))
        if unknown:
            return _error_response(unknown)
        try:
            return JSONResponse(parse_calib(body.get("calib")))
        except BadInput as e:
            return _error_response([e])
