"""The rule for a ``--calib FILE`` of the commands, shared by ``stereodepth match`` and
``stereodepth batch``: the file's format says whether the pair is already rectified.

- A Middlebury ``calib.txt`` or a KITTI calibration file describes a rectified pair: it is
  matched as it is, with the rig the file gives.
- Any other calibration :func:`stereodepth.calib.read_stereo_calibration` reads (OpenCV
  FileStorage YAML/XML/JSON, Kalibr camchain, a pair of ROS camera_info files with
  ``--calib-right``; ``--translation-unit`` the unit of its translations) describes a raw pair,
  rectified automatically before matching by
  :meth:`stereodepth.StereoRectifier.from_calibration` (the file's own R1, R2, P1, P2 where it
  holds them, else Bouguet's method with alpha -1; ``--alpha A`` recomputes them with
  Bouguet's method and that alpha: 0 crops to valid pixels, 1 keeps every raw pixel). The rig
  is then the rectifier's (:func:`rectified_rig`), so disparity, depth and points are of the
  rectified left camera, whose frame is the raw left camera's rotated by R1
  (``x_rect = R1 @ x_raw``).
  ``--no-rectify`` refuses: a raw calibration is then an error. A vertical rig (the rectified
  baseline along y, the first camera above the second) is matched on the transposed rectified
  pair, whose epipolar lines are rows (:func:`along_rows`), and its disparity transposed back
  (:func:`from_rows`): disparity, depth and points are still of the rectified first camera, in
  its image's own orientation; disparity is then ``y1 - y2``.

Errors are ValueError, one line in the flags' names; each command turns them into its usage
error (exit status 2).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from .cli import path_arg

#: Flags that only apply to a raw --calib file.
RAW_ONLY_FLAGS = (
    "--calib-right",
    "--translation-unit",
    "--distortion-model",
    "--image-size",
    "--write-rectified",
    "--alpha",
)


def _raw_only_given(
    calib_right: str | None,
    translation_unit: str | None,
    distortion_model: str | None,
    image_size: tuple[int, int] | None,
    write_rectified: bool,
    alpha: float | None,
) -> list[str]:
    """Which of :data:`RAW_ONLY_FLAGS` were given, in that order."""
    given = (
        calib_right is not None,
        translation_unit is not None,
        distortion_model is not None,
        image_size is not None,
        write_rectified,
        alpha is not None,
    )
    return [flag for flag, g in zip(RAW_ONLY_FLAGS, given, strict=True) if g]


def add_raw_flags(group: Any) -> None:
    """Adds the flags of a raw ``--calib`` file that both commands take (``--calib-right``
    to ``--no-rectify``; each command words its own ``--calib``) to an argparse group."""
    from .calib import TRANSLATION_UNITS

    group.add_argument(
        "--calib-right",
        type=path_arg,
        metavar="FILE",
        help="the right camera's ROS camera_info file (--calib is the left one's), or the "
        "second file of an OpenCV calibration split in two (intrinsics.yml, extrinsics.yml)",
    )
    group.add_argument(
        "--translation-unit",
        choices=tuple(TRANSLATION_UNITS),
        help="unit of the translations in a raw --calib file (default: metres, and a file "
        "whose baseline would then exceed 10 m is refused as probably in mm)",
    )
    group.add_argument(
        "--distortion-model",
        choices=("plumb_bob", "equidistant"),
        help="the distortion model of a raw OpenCV --calib file that does not say (one with 4 "
        "coefficients: equidistant for cv2.fisheye's k1..k4, plumb_bob for k1 k2 p1 p2)",
    )
    group.add_argument(
        "--image-size",
        nargs=2,
        type=int,
        metavar=("WIDTH", "HEIGHT"),
        help="the raw images' size for a raw --calib file that does not give it (OpenCV's "
        "stereo_calib sample's intrinsics.yml and extrinsics.yml, say)",
    )
    group.add_argument(
        "--alpha",
        type=float,
        metavar="A",
        help="with a raw --calib file: recompute the rectification with this alpha (0: crop "
        "to valid pixels, 1: keep every raw pixel, -1: OpenCV's default scaling); default: "
        "the file's own rectification, else alpha -1",
    )
    group.add_argument(
        "--no-rectify",
        action="store_true",
        help="never rectify: a --calib file of a raw (unrectified) pair is an error",
    )


def _cli_names(message: str) -> str:
    """A reader's message with its keyword names replaced by the commands' flags."""
    for name, flag in (
        ("image_size: image_size must be", "--image-size must be"),
        ("second_path", "--calib-right"),
        ("translation_unit", "--translation-unit"),
        ("distortion_model=", "--distortion-model"),
        ("distortion_model does not apply", "--distortion-model does not apply"),
        ("pass image_size=(width, height)", "pass --image-size WIDTH HEIGHT"),
        ("image_size= ", "--image-size "),
        ("image_size must be", "--image-size must be"),
    ):
        message = message.replace(name, flag)
    return message


def flags(args: Any) -> dict[str, Any]:
    """The raw-calibration flags of a command's parsed arguments, as the keywords of
    :func:`check_without_calib` and :func:`raw_calibration` (both commands have them all)."""
    return {
        "calib_right": args.calib_right,
        "translation_unit": args.translation_unit,
        "distortion_model": args.distortion_model,
        "image_size": None if args.image_size is None else tuple(args.image_size),
        "no_rectify": args.no_rectify,
        "write_rectified": args.write_rectified,
        "alpha": args.alpha,
    }


def check_without_calib(
    *,
    calib_right: str | None,
    translation_unit: str | None,
    no_rectify: bool,
    write_rectified: bool,
    alpha: float | None = None,
    distortion_model: str | None = None,
    image_size: tuple[int, int] | None = None,
) -> None:
    """Without ``--calib``: ValueError for a flag that goes with it."""
    given = _raw_only_given(
        calib_right, translation_unit, distortion_model, image_size, write_rectified, alpha
    )
    if no_rectify:
        given.append("--no-rectify")
    if given:
        raise ValueError(f"{given[0]} goes with --calib FILE")


def calibration_source(calib: str, calib_right: str | None) -> str:
    """How records and summaries name a raw calibration: the file, and the right camera's."""
    return calib if calib_right is None else f"{calib}, {calib_right}"


def raw_calibration(
    calib: str,
    *,
    calib_right: str | None = None,
    translation_unit: str | None = None,
    no_rectify: bool = False,
    write_rectified: bool = False,
    alpha: float | None = None,
    distortion_model: str | None = None,
    image_size: tuple[int, int] | None = None,
) -> Any:
    """The :class:`stereodepth.calib.StereoCalibration` of ``--calib`` when it describes a raw
    pair (to be rectified), None when it is a Middlebury or KITTI calibration of a rectified
    pair (matched as given; the raw-only flags are then refused).

    Raises ValueError (one line, in the flags' names) for a missing or unreadable file, a
    raw-only flag with a rectified file, a raw file with ``no_rectify``, and whatever the
    reader finds wrong; ImportError when a YAML file needs PyYAML (the ``calib`` extra)."""
    from .calib import read_stereo_calibration, rectified_format
    from .io import require_file

    try:
        path = require_file(calib, "calibration file")
    except OSError as exc:  # missing, or a folder
        raise ValueError(f"--calib: {exc}") from None
    try:
        rectified = rectified_format(path) is not None
    except OSError as exc:
        raise ValueError(f"--calib: cannot read {calib}: {exc.strerror}") from None
    except ValueError as exc:
        raise ValueError(f"--calib: {exc}") from None
    if rectified:
        given = _raw_only_given(
            calib_right, translation_unit, distortion_model, image_size, write_rectified, alpha
        )
        if given:
            raise ValueError(
                f"{given[0]} does not apply to {calib}, a Middlebury or KITTI calibration "
                "of a pair that is already rectified"
            )
        return None
    try:
        stereo = read_stereo_calibration(
            calib,
            second_path=calib_right,
            translation_unit=translation_unit,
            distortion_model=distortion_model,
            image_size=image_size,
        )
    except ImportError as exc:  # a missing extra (PyYAML): the commands exit with status 1
        raise ImportError(f"--calib: {exc}") from None
    except (OSError, ValueError) as exc:
        text = _cli_names(str(exc))
        # A fault of the second file (it names it first) is --calib-right's.
        second = calib_right is not None and (
            getattr(exc, "filename", None) == calib_right
            or text.startswith((f"{calib_right}:", f"{Path(calib_right).name}:"))
        )
        raise ValueError(f"{'--calib-right' if second else '--calib'}: {text}") from None
    if stereo.rectified:  # not from the raw formats today; refuse rather than guess
        raise ValueError(f"--calib: {calib} is read as a rectified pair of unknown format")
    if no_rectify:
        raise ValueError(
            f"--calib: {calib} is the calibration of a raw (unrectified) pair and "
            "--no-rectify forbids rectifying it: drop --no-rectify, or give a Middlebury or "
            "KITTI calibration of a rectified pair"
        )
    return stereo


def check_alpha(alpha: Any) -> float | None:
    """``--alpha``: None, -1 (OpenCV's default scaling) or a number in [0, 1]; ValueError
    naming the flag otherwise."""
    if alpha is None:
        return None
    a = float(alpha)
    if not (a == -1 or 0 <= a <= 1):  # NaN fails both
        raise ValueError(f"--alpha must be -1 (OpenCV's default scaling) or in [0, 1], got {a}")
    return a


def raw_rectifier(
    stereo: Any, calib: str, *, threads: int | None = None, alpha: float | None = None
) -> Any:
    """The :class:`stereodepth.StereoRectifier` of a raw calibration read by
    :func:`raw_calibration` (``calib`` its file, for messages); ``alpha`` (``--alpha``) None
    uses the file's own transforms where it has them, else Bouguet's with alpha -1. Raises
    ValueError for a bad ``alpha``, when it cannot rectify, or when its rig is refused (a first
    camera to the right of, or below, the second)."""
    from .rectify import StereoRectifier

    alpha = check_alpha(alpha)
    if alpha is not None and alpha != -1 and stereo.distortion_model == "equidistant":
        # from_calibration's message named "alpha" and the balance and fov_scale keywords,
        # which no flag gives.
        raise ValueError(
            f"--alpha applies to pinhole calibrations; {calib} is an equidistant (fisheye) one, "
            "rectified as cv2.fisheye.stereoRectify does with balance 0: drop --alpha"
        )
    try:
        rectifier = StereoRectifier.from_calibration(stereo, threads=threads, alpha=alpha)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"--calib: {calib}: cannot rectify: {exc}") from None
    try:
        rectifier.rig  # noqa: B018 - refuses a pair whose first camera is the right one
    except ValueError as exc:
        stored = alpha is None and stereo.P1 is not None and stereo.P2 is not None
        # The file's own R1, R2, P1, P2 were computed from its R and T: a change of T (or of
        # the cameras' order) leaves them as they were, and the rig still refused.
        hint = (
            "; this file also holds R1, R2, P1, P2, made from its R and T: after correcting "
            "those, delete them or pass --alpha -1 to compute them anew"
            if stored
            else ""
        )
        raise ValueError(f"--calib: {calib}: {exc}{hint}") from None
    return rectifier


def along_rows(vertical: bool, left: Any, right: Any) -> tuple[Any, Any]:
    """The rectified pair as the matchers search it, along rows: as it is for a horizontal rig,
    transposed ((H, W[, 3]) to (W, H[, 3]), contiguous copies) for a vertical one."""
    if not vertical:
        return left, right
    import numpy as np

    return tuple(np.ascontiguousarray(np.swapaxes(a, 0, 1)) for a in (left, right))  # type: ignore[return-value]


def from_rows(vertical: bool, array: Any) -> Any:
    """A (H, W) map computed on :func:`along_rows`'s pair, back in the rectified images'
    orientation (transposed for a vertical rig)."""
    if not vertical or array is None:
        return array
    import numpy as np

    return np.ascontiguousarray(array.T)


@contextlib.contextmanager
def matched_along_rows(vertical: bool, height: int) -> Iterator[None]:
    """Around matching :func:`along_rows`'s pair: for a vertical rig, a ValueError from the
    matcher, which speaks of the transposed pair (its "width" and "columns" are the rectified
    images' height and rows), says so and gives that ``height`` in pixels."""
    try:
        yield
    except ValueError as exc:
        if not vertical:
            raise
        raise ValueError(
            f"{exc} (a vertical rig: the pair is matched transposed, along its columns, so the "
            f"image's width and columns above are the rectified images' height of {height} "
            f"pixels and their rows)"
        ) from exc


def rectified_rig(rectifier: Any) -> dict[str, float]:
    """The rig of the rectified pair: ``focal_px``, ``baseline_m``, ``doffs_px`` of
    ``rectifier.rig``, and the rectified left camera's principal point ``cx_px``, ``cy_px``
    from P1."""
    r = rectifier.rig
    P1 = rectifier.P1
    return {
        "focal_px": float(r.focal_px),
        "baseline_m": float(r.baseline_mm) / 1000.0,
        "doffs_px": float(r.doffs_px),
        "cx_px": float(P1[0, 2]),
        "cy_px": float(P1[1, 2]),
    }


def rig_range_problem(
    focal_px: float, baseline_m: float, doffs_px: float, *, flags: bool = False
) -> str | None:
    """Why the commands' float32 depth maps cannot hold this rig's depths, or None: the rule of
    :func:`stereodepth.disparity_to_depth` for float32 disparity (focal_px * baseline_m within
    float32's normal range, ``|doffs_px|`` within float32's range), said in the rig's terms
    (``flags``: in those of ``--focal-px``, ``--baseline-mm`` and ``--doffs-px``), so that a
    command names what the user gave (the library's message names its parameters and suggests
    float64 input, which a command-line user cannot give)."""
    import numpy as np

    f32 = np.finfo(np.float32)
    lo, hi = float(f32.tiny), float(f32.max)
    k = focal_px * baseline_m
    if not lo <= k <= hi:
        rig = (
            f"--focal-px {focal_px:.6g} times --baseline-mm {baseline_m * 1000:.6g}"
            if flags
            else f"focal length {focal_px:.6g} px times baseline {baseline_m:.6g} m"
        )
        return (
            f"{rig} is {k:.4g} px*m, outside the range float32 depth maps can be computed from "
            f"([{lo:.4g}, {hi:.4g}] px*m): check the units"
        )
    if not abs(doffs_px) <= hi:
        name = "--doffs-px" if flags else "doffs"
        return (
            f"{name} {doffs_px:.6g} px is outside float32's range (|doffs| <= {hi:.4g}): check "
            "the units"
        )
    return None


def write_png(path: Path, image: Any) -> None:
    """An 8-bit grey or RGB, or a 16-bit grey image as a PNG, atomically (the rectified
    images of ``--write-rectified``)."""
    import numpy as np

    from . import io

    if image.dtype == np.uint16:
        io.write_png16(path, image)
        return
    from PIL import Image

    with io.atomic_write(path) as f:
        Image.fromarray(np.ascontiguousarray(image)).save(f, format="PNG")
