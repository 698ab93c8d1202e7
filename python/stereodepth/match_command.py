"""``stereodepth match LEFT RIGHT``: one rectified pair to disparity, depth, colour previews and
a point cloud, with a summary on stdout (``--json`` for one JSON object).

Outputs go to ``--out``: a folder (an existing one, or a path ending in ``/``, created) with
files ``disparity.<ext>``, ``depth.<ext>``, ``disparity-preview.png``, ``depth-preview.png``
and ``points.ply``; or a prefix (``--out results/teddy-`` writes ``results/teddy-disparity.pfm``
and so on; its folder must exist). A file already at one of the output names that no earlier
``match`` run there wrote (its hidden record does not list it) is refused, exit 2, unless
``--force``. Formats: disparity as PFM (float32, +inf holes, as
Middlebury's; default), ``npy`` (float32, NaN holes) or ``png16`` (KITTI's uint16 of d x 256, 0
for holes: 0 to 255.996 px, refused for a search range outside that); depth as ``npy`` (float32
metres, NaN where unknown; default), ``pfm``, or ``png16`` (uint16 millimetres, 0 unknown,
1 for 1 mm and nearer, 65535 for 65.535 m and farther).
The previews are the colourised maps pixel for pixel with a colour bar and unit under them
(:func:`stereodepth.save_colorized`); they need the ``plot`` extra (``--no-preview`` skips them).

Depth needs a rig: ``--calib FILE`` or ``--focal-px`` and ``--baseline-mm`` (with
``--doffs-px``). Without one only the disparity is written.

The rule for ``--calib``: the file's format says whether the pair is already rectified.

- A Middlebury ``calib.txt`` or a KITTI calibration file describes a rectified pair: LEFT and
  RIGHT are matched as they are, with the rig the file gives (and Middlebury's ``ndisp``).
- Any other calibration :func:`stereodepth.calib.read_stereo_calibration` reads (OpenCV
  FileStorage YAML/XML/JSON, Kalibr camchain, a ROS camera_info file with ``--calib-right FILE``
  for the right camera; ``--translation-unit`` the unit of its translations, default metres, refused
  for an OpenCV file whose baseline would then exceed 10 m; ``--distortion-model`` the model of
  an OpenCV file with 4 coefficients that does not name it, refused without it;
  ``--image-size`` for a file without one; ``--calib-right`` also the second file of an
  OpenCV calibration split in two)
  describes a raw pair, which is rectified automatically before matching:
  :meth:`stereodepth.StereoRectifier.from_calibration` (the file's own R1, R2, P1, P2 where
  it holds them, else Bouguet's method with alpha -1; ``--alpha A`` recomputes them with
  Bouguet's method and that alpha), then ``rectify(LEFT, RIGHT)``. The
  rig is ``rectifier.rig`` (focal_px, baseline, doffs) with cx, cy from P1, so the disparity,
  depth, previews and point cloud are all of the rectified left camera (its frame is the raw
  left camera's rotated by R1, ``x_rect = R1 @ x_raw``), at the rectified size. The summary
  says ``rectified: true`` with ``rectified_size`` ``[width, height]``; ``--write-rectified``
  also writes the rectified pair as ``left-rectified.png`` and ``right-rectified.png``.
  ``--no-rectify`` refuses to rectify: a raw calibration is then an error. A vertical rig
  (first camera above the second) is matched on the transposed rectified pair and its
  disparity (``y1 - y2``) transposed back, so every output is in the rectified first camera's
  orientation.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import re
import secrets
import stat
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from . import _calib_rule
from .cli import name_too_long, outputs_committed, path_arg, signals_held

__all__ = ["output_paths", "register", "run"]

DISPARITY_FORMATS = {"pfm": ".pfm", "npy": ".npy", "png16": ".png"}
DEPTH_FORMATS = {"npy": ".npy", "pfm": ".pfm", "png16": ".png"}


class _Usage(ValueError):
    """Bad input on the command line (exit status 2)."""


def register(subparsers: Any) -> None:
    """Adds the ``match`` subcommand."""
    p = subparsers.add_parser(
        "match",
        help="one stereo pair to disparity, depth, colour previews and a point cloud",
        description=(
            "Matches one stereo pair and writes the disparity, the depth (with a "
            "calibration), colour previews with colour bars and optionally a PLY point cloud; "
            "prints a summary (size, search range, density, depth range, time). The pair is "
            "matched as given with a Middlebury or KITTI --calib (rectified pairs), and "
            "rectified first with any other calibration (a raw pair: OpenCV, Kalibr, ROS); "
            "then every output is of the rectified left camera, in its frame."
        ),
    )
    p.add_argument("left", type=path_arg, metavar="LEFT", help="the left image (PNG, JPEG, ...)")
    p.add_argument("right", type=path_arg, metavar="RIGHT", help="the right image, the same size")
    from ._methods import block_sizes_text
    from .matching import (
        DEFAULT_BLOCK_SIZE,
        MAX_ABS_MIN_DISPARITY,
        MAX_BLOCK_SIZE,
        MAX_NUM_DISPARITIES,
    )
    from .semi_global import DEFAULT_BLOCK_SIZE as SGM_BLOCK_SIZE

    m = p.add_argument_group("the matcher")
    m.add_argument(
        "--method",
        choices=("bm", "sgm"),
        default="bm",
        help="bm: block matching (default); sgm: semi-global matching (more accurate, slower)",
    )
    m.add_argument(
        "--num-disparities",
        type=int,
        metavar="N",
        help=f"disparities searched, 1 to {MAX_NUM_DISPARITIES} with either method (default: "
        "ndisp of a Middlebury calib.txt, else an eighth of the width rounded up to 16, from "
        "16 to 256)",
    )
    m.add_argument(
        "--min-disparity",
        type=int,
        default=0,
        metavar="N",
        help=f"the smallest disparity searched, an integer from {-MAX_ABS_MIN_DISPARITY} to "
        f"{MAX_ABS_MIN_DISPARITY}, either method (default 0)",
    )
    costs, sgm_sizes = block_sizes_text()
    m.add_argument(
        "--block-size",
        type=int,
        metavar="N",
        help=f"the side of the matching block, by method: bm an odd number, {costs} (default "
        f"{DEFAULT_BLOCK_SIZE}); sgm {sgm_sizes} only, the box its census costs are summed "
        f"over (default {SGM_BLOCK_SIZE})",
    )
    m.add_argument(
        "--cost",
        choices=tuple(MAX_BLOCK_SIZE),
        help="the block matcher's cost (default census); --method bm only",
    )
    m.add_argument(
        "--threads",
        type=int,
        metavar="N",
        help="threads, an integer >= 0, either method (default, or 0: every core)",
    )
    r = p.add_argument_group("the rig (for depth)")
    r.add_argument(
        "--calib",
        type=path_arg,
        metavar="FILE",
        help="Middlebury calib.txt or KITTI calib (rectified pairs: matched as given), or a raw "
        "calibration (OpenCV FileStorage YAML/XML/JSON, Kalibr camchain, ROS camera_info): the "
        "pair is rectified first and the depth is in the rectified left camera's frame",
    )
    _calib_rule.add_raw_flags(r)
    r.add_argument("--focal-px", type=float, metavar="PX", help="focal length in pixels")
    r.add_argument("--baseline-mm", type=float, metavar="MM", help="baseline in millimetres")
    r.add_argument(
        "--doffs-px", type=float, metavar="PX", help="principal point offset in px (default 0)"
    )
    o = p.add_argument_group("output")
    o.add_argument(
        "-o",
        "--out",
        type=path_arg,
        default=".",
        metavar="PATH",
        help="a folder (existing, or ending in /) or a file-name prefix (default: .; "
        "-o results/teddy- writes results/teddy-disparity.pfm, ...). A run replaces the whole "
        "set of match's files there: once its own are written it removes those an earlier run "
        "wrote that it does not write (another format, a points.ply, previews or rectified "
        "pair not asked for this time; listed as 'removed'), as a hidden record there lists "
        "them and if they are unchanged since; a failed run leaves the earlier set as it was. "
        "Other files are never touched: a file at one of its output names that the record "
        "does not list is refused (see --force)",
    )
    o.add_argument(
        "--force",
        action="store_true",
        help="replace files at the output names that no earlier match run at --out wrote "
        "(refused without it: a depth.npy of yours in the folder, say)",
    )
    o.add_argument(
        "--disparity-format", choices=tuple(DISPARITY_FORMATS), default="pfm", help="default pfm"
    )
    o.add_argument(
        "--depth-format",
        choices=tuple(DEPTH_FORMATS),
        default="npy",
        help="npy or pfm: float32 m; png16: uint16 mm, 0 unknown, 1 for 1 mm and nearer, "
        "65535 for 65.535 m and farther (default npy)",
    )
    o.add_argument("--no-preview", action="store_true", help="skip the colour previews")
    o.add_argument(
        "--cmap", default="turbo", metavar="NAME", help="colour map of the previews (turbo)"
    )
    o.add_argument("--ply", action="store_true", help="also write the point cloud as points.ply")
    o.add_argument(
        "--write-rectified",
        action="store_true",
        help="with a raw --calib: also write the rectified pair as left-rectified.png and "
        "right-rectified.png",
    )
    o.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.set_defaults(func=run)


def _out_is_folder(out: str) -> bool:
    """Whether ``--out`` names a folder (an existing one, or a path ending in a separator),
    rather than a prefix of the file names."""
    return out.endswith(("/", os.sep)) or Path(out).is_dir()


def _missing_folders(out: str) -> list[Path]:
    """The folders :func:`output_paths` would make for ``out`` (a folder that does not exist
    yet and its missing parents), deepest first; none for a prefix."""
    if not _out_is_folder(out):
        return []
    missing = []
    folder = Path(out).absolute()
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return missing


def output_paths(out: str, names: list[str]) -> dict[str, Path]:
    """Where each output goes: ``out`` as a folder (existing, or ending in a separator: made)
    or as a prefix of the file names (its folder must exist). An output name taken by a folder
    is refused before anything is written, and so is a prefix that makes a name longer than a
    file name may be (it was "[Errno 36] File name too long", exit status 1, naming no
    option)."""
    for part in (Path(out + n).name for n in names):  # the folders' names: cli.path_arg
        problem = name_too_long(part)
        if problem is not None:
            raise _Usage(f"--out: {problem}")
    is_dir = _out_is_folder(out)
    if is_dir:
        folder = Path(out)
        if folder.exists() and not folder.is_dir():
            raise _Usage(f"--out must be a folder or a file-name prefix, got {out!r}")
        paths = {n: folder / n for n in names}
    else:
        parent = Path(out).parent
        if not parent.is_dir():
            raise _Usage(f"--out: the folder of the prefix {out!r} does not exist: {str(parent)!r}")
        if os.path.lexists(out):
            # A prefix that names a file or a device: -o /dev/null wrote /dev/nulldisparity.pfm
            # (as root), -o left.png wrote left.pngdisparity.pfm.
            raise _Usage(
                f"--out {out}: an existing file, not a folder; give a folder (ending in "
                f"{os.sep} if new) or a file-name prefix that names no file"
            )
        paths = {n: Path(out + n) for n in names}
    for path in paths.values():
        if path.is_dir():
            raise _Usage(
                f"--out: {str(path)!r} is a folder, so the output of that name cannot be written"
            )
    if is_dir:
        try:
            Path(out).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise _Usage(f"--out: cannot make the folder {out!r}: {exc.strerror}") from None
    return paths


def _rig(
    args: argparse.Namespace,
) -> tuple[dict[str, Any] | None, int | None, str | None, Any]:
    """(focal_px, baseline_m, doffs_px, cx_px, cy_px) or None; ndisp; the calibration's source;
    the StereoRectifier of a raw calibration, else None. The rule for --calib is
    :mod:`stereodepth._calib_rule`'s, shared with ``stereodepth batch``."""
    from . import _calib_rule as rule

    # "is not None": a flag given as 0 is given (and refused below); "if v" left it out, so
    # --focal-px 0 alone was an IndexError and beside --calib was silently ignored.
    given = [
        n
        for n, v in (("--focal-px", args.focal_px), ("--baseline-mm", args.baseline_mm))
        if v is not None
    ]
    if args.calib is None:
        try:
            rule.check_without_calib(**rule.flags(args))
        except ValueError as exc:
            raise _Usage(str(exc)) from None
    if args.calib is not None:
        if given or args.doffs_px is not None:
            raise _Usage("give either --calib or --focal-px and --baseline-mm, not both")
        rectifier = None
        try:
            stereo = rule.raw_calibration(
                args.calib,
                **rule.flags(args),
            )
            if stereo is not None:  # (--threads is checked by run, before this)
                rectifier = rule.raw_rectifier(
                    stereo, args.calib, threads=args.threads, alpha=args.alpha
                )
        except _Usage:
            raise
        except ValueError as exc:
            raise _Usage(str(exc)) from None
        if rectifier is not None:
            source = rule.calibration_source(args.calib, args.calib_right)
            return rule.rectified_rig(rectifier), None, source, rectifier
        from .match_pair import kitti_cameras, read_calibration_file

        try:
            # A KITTI file holds four cameras: those of the images' folders (image_0/image_1,
            # the grey pair, have another baseline than image_2/image_3), as batch reads them.
            c = read_calibration_file(args.calib, kitti_cameras(args.left, args.right))
        except (OSError, ValueError) as exc:
            raise _Usage(f"--calib: {exc}") from None
        rig: dict[str, Any] = {
            "focal_px": float(c.focal_px),
            "baseline_m": float(c.baseline_m),
            "doffs_px": float(c.doffs_px),
            "cx_px": c.cx_px,
            "cy_px": c.cy_px,
            "image_size": getattr(c, "image_size", None),  # the file's width and height
        }
        return rig, c.num_disparities, str(args.calib), None
    if args.focal_px is None and args.baseline_mm is None:
        if args.doffs_px is not None:
            raise _Usage("--doffs-px goes with --focal-px and --baseline-mm")
        return None, None, None, None
    if args.focal_px is None or args.baseline_mm is None:
        missing = "--baseline-mm" if args.focal_px is not None else "--focal-px"
        raise _Usage(f"{missing} is required with {given[0]}")
    for name, v in (("--focal-px", args.focal_px), ("--baseline-mm", args.baseline_mm)):
        if not (np.isfinite(v) and v > 0):
            raise _Usage(f"{name} must be a finite number > 0, got {v!r}")
    doffs = 0.0 if args.doffs_px is None else float(args.doffs_px)
    if not np.isfinite(doffs):
        raise _Usage(f"--doffs-px must be finite, got {doffs!r}")
    rig = {
        "focal_px": float(args.focal_px),
        "baseline_m": float(args.baseline_mm) / 1000.0,
        "doffs_px": doffs,
        "cx_px": None,
        "cy_px": None,
    }
    return rig, None, "command line", None


def _refuse_overwriting_inputs(args: argparse.Namespace, out: dict[str, Path]) -> None:
    """A usage error when an output would replace one of the command's own input files (the
    images or the calibration): ``match left-rectified.png right-rectified.png
    --write-rectified -o .`` used to overwrite the raw pair it was given."""
    given = [
        (flag, value)
        for flag, value in (
            ("LEFT", args.left),
            ("RIGHT", args.right),
            ("--calib", args.calib),
            ("--calib-right", args.calib_right),
        )
        if value is not None
    ]
    for path in out.values():
        if not path.exists():
            continue
        for flag, value in given:
            try:
                same = os.path.samefile(path, value)
            except OSError:
                continue
            if same:
                raise _Usage(
                    f"--out: {str(path)!r} would overwrite {flag} {value!r}: choose another "
                    "--out folder or prefix"
                )


def _check_matcher_flags(args: argparse.Namespace, num_disparities: int) -> None:
    """The matcher flags checked by the matcher's own rules before any work or any file is
    written, each error naming the flag as typed (``--block-size 4: block_size must be ...``);
    ``--cost`` first, as the block sizes the block matcher takes depend on it."""
    from ._methods import matcher_keywords, options_class

    checker = options_class(args.method)
    known = matcher_keywords(args.method)
    flags = (
        ("--cost", "cost", args.cost),
        ("--num-disparities", "num_disparities", args.num_disparities),
        ("--min-disparity", "min_disparity", args.min_disparity),
        ("--block-size", "block_size", args.block_size),
    )
    context: dict[str, Any] = {"num_disparities": num_disparities}
    if args.num_disparities is None and args.calib is not None:
        # The calibration's ndisp: its error was blamed on the first flag checked after it
        # (--min-disparity 0, a flag not even given).
        try:
            checker(num_disparities=num_disparities)
        except (TypeError, ValueError) as exc:
            raise _Usage(
                f"--calib {args.calib}: its ndisp={num_disparities} is no search range for "
                f"--method {args.method} ({exc}): give --num-disparities N"
            ) from None
    for flag, key, value in flags:
        if value is None:
            continue
        if key not in known:
            raise _Usage(f"{flag}: --method {args.method} has no {key}, got {value!r}")
        try:
            checker(**{**context, key: value})
        except (TypeError, ValueError) as exc:
            raise _Usage(f"{flag} {value}: {exc}") from None
        context[key] = value


def _read(name: str, path: str) -> np.ndarray:
    from .io import read_image

    try:
        return read_image(path)
    except (OSError, ValueError) as exc:
        raise _Usage(f"{name}: {exc}") from None


def run(args: argparse.Namespace) -> int:
    """Matches the pair, writes the outputs, prints the summary; returns the exit status."""
    from . import _calib_rule as rule
    from .cli import threads_out_of_range
    from .match_pair import default_num_disparities, match_pair, prepare_pair

    # Before the rig: a raw calibration's rectifier is made with these threads.
    if why := threads_out_of_range(args.threads):
        raise _Usage(why)
    rig, ndisp, source, rectifier = _rig(args)
    if rig is not None:
        flags = source == "command line"
        why = rule.rig_range_problem(
            rig["focal_px"], rig["baseline_m"], rig["doffs_px"], flags=flags
        )
        if why is not None:
            raise _Usage(why if flags else f"--calib {source}: {why}")
    left_img = _read("LEFT", args.left)
    right_img = _read("RIGHT", args.right)
    if left_img.shape[:2] != right_img.shape[:2]:
        raise _Usage(
            f"LEFT and RIGHT must have the same size, got {left_img.shape[1]}x"
            f"{left_img.shape[0]} and {right_img.shape[1]}x{right_img.shape[0]} px"
        )
    calib_size = rectifier.image_size if rectifier is not None else (rig or {}).get("image_size")
    if calib_size is not None:
        # A calibration of another resolution (Middlebury's full-size calib.txt for its
        # quarter-size images) gives depths off by the scale factor, silently.
        cw, ch = calib_size
        if left_img.shape[:2] != (ch, cw):
            raise _Usage(
                f"LEFT and RIGHT must have the size of the calibration in --calib, {cw}x{ch} "
                f"px, got {left_img.shape[1]}x{left_img.shape[0]} px"
            )
    if os.path.samefile(args.left, args.right):  # batch's CSV lists refuse this too
        raise _Usage(
            f"LEFT and RIGHT are the same file ({args.left!r} and {args.right!r}): give the "
            "two images of the pair"
        )
    # The search range the checks assume: the one match_pair uses (the matched width's default
    # when neither the flag nor the calibration gives one; the checks do not depend on it).
    checked_nd = args.num_disparities if args.num_disparities is not None else ndisp
    _check_matcher_flags(args, checked_nd or default_num_disparities(right_img.shape[1]))
    reach = args.min_disparity + (checked_nd or default_num_disparities(right_img.shape[1]))
    if args.disparity_format == "png16" and reach > 256:  # KITTI's PNG: at most 65535 / 256
        raise _Usage(
            f"--disparity-format png16 holds disparities up to 255.996 px, and the search "
            f"reaches {reach - 1} px (--min-disparity + --num-disparities - 1): use pfm or npy"
        )
    if args.disparity_format == "png16" and args.min_disparity < 0:  # it has no negatives
        raise _Usage(
            f"--disparity-format png16 holds no negative disparities (KITTI's d x 256, 0 for "
            f"none), and --min-disparity {args.min_disparity} searches them: they would be "
            "written as holes; use pfm or npy"
        )
    want_preview = not args.no_preview
    if want_preview:
        from .cli import import_uninterrupted
        from .colormap import _INSTALL_HINT, colormap_lut

        try:
            import_uninterrupted("matplotlib", "matplotlib.colors")
        except ImportError as exc:
            raise ImportError(_INSTALL_HINT) from exc
        try:  # a bad name or a missing extra (ImportError, exit 1) fails before any work
            colormap_lut(args.cmap)
        except ValueError as exc:  # named the library's cmap, not the flag
            raise _Usage(f"--cmap {args.cmap}: {exc}") from None
    names = {"disparity": "disparity" + DISPARITY_FORMATS[args.disparity_format]}
    if rig is not None:
        names["depth"] = "depth" + DEPTH_FORMATS[args.depth_format]
    if want_preview:
        names["disparity_preview"] = "disparity-preview.png"
        if rig is not None:
            names["depth_preview"] = "depth-preview.png"
    if args.ply:
        if rig is None:
            raise _Usage("--ply needs a rig: give --calib or --focal-px and --baseline-mm")
        names["ply"] = "points.ply"
    if args.write_rectified:
        names["left_rectified"] = "left-rectified.png"
        names["right_rectified"] = "right-rectified.png"
    made = _missing_folders(args.out)  # what output_paths makes of a new --out folder
    paths = output_paths(args.out, list(names.values()))
    try:
        out = {key: paths[name] for key, name in names.items()}
        _refuse_overwriting_inputs(args, out)
        from .io import _refuse_read_only

        # Before any work: a folder the outputs cannot be written in, and (as a read-only
        # output) a file of an earlier run that cannot be replaced, are usage errors naming
        # --out (they failed after the match, naming the hidden file being written).
        folder = next(iter(out.values())).parent.absolute()
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
        if folder.is_dir() and not os.access(folder, os.W_OK | os.X_OK):
            raise _Usage(f"--out {args.out}: cannot write in {folder} (no write permission)")
        try:
            for path in out.values():  # (a link is written through: its target)
                _refuse_read_only(Path(os.path.realpath(path)), path)
            for path in _stale_outputs(args, names):
                if not path.is_symlink():
                    _refuse_read_only(path, path)
        except PermissionError as exc:
            raise _Usage(f"--out {args.out}: {exc.strerror}") from None
        if not args.force:
            _refuse_replacing_files_of_no_record(args.out, out, names)

        rectify_s = None
        if rectifier is not None:
            # The pair as the rectified cameras see it; everything below is in their frame.
            left_img, right_img = prepare_pair(left_img, right_img)
            t0 = time.perf_counter()
            left_img, right_img = rectifier.rectify(left_img, right_img)
            rectify_s = time.perf_counter() - t0
        vertical = rectifier is not None and rectifier.vertical
        rows_left, rows_right = rule.along_rows(vertical, left_img, right_img)
        with rule.matched_along_rows(vertical, left_img.shape[0]):
            result = match_pair(
                rows_left,
                rows_right,
                method=args.method,
                num_disparities=args.num_disparities if args.num_disparities is not None else ndisp,
                min_disparity=args.min_disparity,
                block_size=args.block_size,
                cost=args.cost,
                focal_px=None if rig is None else rig["focal_px"],
                baseline_m=None if rig is None else rig["baseline_m"],
                doffs_px=0.0 if rig is None else rig["doffs_px"],
                threads=args.threads,
            )
        if vertical:  # back in the rectified images' orientation
            result = dataclasses.replace(
                result,
                disparity=rule.from_rows(True, result.disparity),
                confidence=rule.from_rows(True, result.confidence),
                depth=rule.from_rows(True, result.depth),
            )
        # The set is written beside its final names first and renamed into place only once
        # every file and the summary are written: a run that fails or is stopped (Ctrl-C,
        # SIGTERM) leaves none of its outputs and the earlier run's set as it was, as a new
        # disparity beside an old depth would pass for one result.
        _remove_killed_runs_files(args.out)
        staged = _staging_paths(out)
        try:
            try:
                _write_outputs(args, staged, result, rig, left_img, right_img)
            except OSError as exc:  # name the output, not the hidden file it is staged as
                final = {str(v): out[k] for k, v in staged.items()}.get(exc.filename)
                if final is None:
                    raise
                why = str(exc.strerror).removeprefix(f"cannot write {Path(exc.filename).name}: ")
                raise type(exc)(exc.errno, f"cannot write {final}: {why}", str(final)) from None
            stale = _stale_outputs(args, names)
            summary = result.summary()
            summary.update(
                {
                    "left": str(args.left),
                    "right": str(args.right),
                    "calibration": source,
                    "rectified": rectifier is not None,
                    "outputs": {k: str(v) for k, v in out.items()},
                    "removed": [str(p) for p in stale],
                }
            )
            if rectifier is not None:
                summary["raw_size"] = list(rectifier.image_size)
                summary["rectified_size"] = list(rectifier.output_size)
                summary["rectify_time_s"] = rectify_s
            # The summary before the commit: a summary that cannot be printed (stdout full or
            # closed) fails the run, and then it leaves no outputs.
            _print_summary(summary, left_img, as_json=args.json)
            # From the commit on the run completes: Ctrl-C and SIGTERM are held until the
            # record of the set is written too, and one that comes later no longer says
            # "stopped" (130, 143), which would mean the earlier set was left as it was.
            with signals_held():
                _commit(staged, out, stale)
                _write_manifest(args.out, out, names)
                outputs_committed()
        finally:
            for tmp in staged.values():
                if tmp not in out.values():  # a staged file not renamed into place
                    with contextlib.suppress(OSError):
                        tmp.unlink()
    except BaseException:
        # A failed run (the matcher refused the pair, a write failed) leaves no new
        # empty --out folder behind: it left one, made before the pair was matched.
        for folder in made:
            with contextlib.suppress(OSError):
                folder.rmdir()  # only when empty
        raise
    return 0


#: Every file name match writes, in every format: the set an --out folder or prefix holds.
OWNED_NAMES: tuple[str, ...] = (
    *dict.fromkeys(
        [
            *("disparity" + ext for ext in DISPARITY_FORMATS.values()),
            *("depth" + ext for ext in DEPTH_FORMATS.values()),
        ]
    ),
    "disparity-preview.png",
    "depth-preview.png",
    "points.ply",
    "left-rectified.png",
    "right-rectified.png",
)


def _print_summary(summary: dict[str, Any], left: np.ndarray, *, as_json: bool) -> None:
    """Prints and flushes the summary; OSError saying so when it cannot reach stdout (full,
    or closed: Python then has no sys.stdout, and print() wrote nothing without a word).
    BrokenPipeError (the reader went away) as it is."""
    if sys.stdout is None:
        raise OSError("cannot print the summary: stdout is closed")
    try:
        if as_json:
            print(json.dumps(summary, indent=2, allow_nan=False))
        else:
            _print(summary, left)
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise OSError(f"cannot print the summary: {exc.strerror or exc}") from None


def _staging_paths(out: dict[str, Path]) -> dict[str, Path]:
    """Where each output is written before the commit: a hidden name beside the file it
    replaces (beside a link's target: a link is written through, as io.atomic_write does),
    with the same suffix. A device or a pipe in an --out folder is written directly. A
    read-only file is refused here as io.atomic_write refuses it: run checks every output
    before the match (naming --out); this catches one made read-only while the pair was
    matched, as renaming over it would succeed."""
    from .io import NAME_MAX_BYTES, _refuse_read_only

    staged = {}
    for key, path in out.items():
        try:
            mode = os.stat(path).st_mode
        except OSError:
            mode = None
        if mode is not None and not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
            staged[key] = path
            continue
        target = Path(os.path.realpath(path)) if path.is_symlink() else path
        _refuse_read_only(target, path)
        tail = f".{_STAGING_MARKER}-{secrets.token_hex(6)}{target.suffix}"
        room = NAME_MAX_BYTES - 1 - len(tail.encode())
        stem = target.stem.encode(errors="surrogateescape")[:room].decode(errors="ignore")
        staged[key] = target.with_name(f".{stem or 'x'}{tail}")
    return staged


_STAGING_MARKER = "stereodepth-match"


def _remove_killed_runs_files(out: str) -> list[Path]:
    """Removes the staged files a killed run (SIGKILL, a power cut) left at ``--out``: hidden
    files named as :func:`_staging_paths` names them for one of :data:`OWNED_NAMES` (a random
    token no other program writes). Returns what it removed."""
    is_dir = _out_is_folder(out)
    folder, prefix = (Path(out), "") if is_dir else (Path(out).parent, Path(out).name)
    token = re.compile(r"\." + _STAGING_MARKER + r"-[0-9a-f]{12}$")
    wanted = {(Path(prefix + n).stem, Path(n).suffix) for n in OWNED_NAMES}
    removed: list[Path] = []
    try:
        entries = list(folder.iterdir())
    except OSError:
        return removed
    for entry in entries:
        name = entry.name
        stem, suffix = Path(name[1:]).stem, Path(name).suffix
        m = token.search(stem) if name.startswith(".") else None
        if m is None or (stem[: m.start()], suffix) not in wanted:
            continue
        with contextlib.suppress(OSError):
            if entry.is_file() and not entry.is_symlink():
                entry.unlink()
                removed.append(entry)
    return removed


#: The record of the files a run wrote, beside them: ``.stereodepth-match.json`` in an --out
#: folder, ``.<prefix>stereodepth-match.json`` beside a prefix's files.
MANIFEST_NAME = "stereodepth-match.json"


def _manifest_path(out: str) -> Path:
    """Where the record of ``--out``'s last run lies."""
    if _out_is_folder(out):
        return Path(out) / f".{MANIFEST_NAME}"
    prefix = Path(out)
    return prefix.with_name(f".{prefix.name}{MANIFEST_NAME}")


def _recorded_files(out: str) -> dict[str, Any]:
    """The files the record of ``--out``'s last run lists, by name, each with the size and
    modification time it had then; none without a readable record."""
    try:
        record = json.loads(_manifest_path(out).read_text(encoding="utf-8"))
        files = record["files"] if isinstance(record, dict) else {}
    except (OSError, ValueError, KeyError):
        return {}
    return files if isinstance(files, dict) else {}


def _refuse_replacing_files_of_no_record(
    out_arg: str, out: dict[str, Path], names: dict[str, str]
) -> None:
    """A usage error, before any work, when a file (or a link) is at one of this run's output
    paths and ``--out``'s record (:func:`_manifest_path`) does not list that name: no match
    run wrote it there, so it is the user's (a ``depth.npy`` of theirs in the folder, the
    default --out being '.'), which used to be replaced without a word. ``--force`` replaces
    it; so does a later run once the record lists it (batch's rule, see its --force). A
    device or a pipe at an output name is written as before."""
    listed = _recorded_files(out_arg)
    for key, path in out.items():
        try:
            st = path.lstat()
        except OSError:
            continue
        if not (stat.S_ISREG(st.st_mode) or stat.S_ISLNK(st.st_mode)) or names[key] in listed:
            continue
        raise _Usage(
            f"--out {out_arg}: {path.name} is there and no earlier match run's record lists "
            "it (a file of yours?): move it, choose another --out, or give --force to replace it"
        )


def _stale_outputs(args: argparse.Namespace, names: dict[str, str]) -> list[Path]:
    """The files of an earlier run at --out that this run does not write (another format, a
    cloud or previews no longer asked for): those its record lists (:func:`_manifest_path`)
    under a name of :data:`OWNED_NAMES`, still as that run left them (same size and
    modification time). A file of such a name that match did not write, or that was changed
    since, is the user's and stays; so does a folder, and one of the command's input files
    (``match left-rectified.png right-rectified.png`` without --write-rectified)."""
    files = _recorded_files(args.out)
    written = set(names.values())
    is_dir = _out_is_folder(args.out)
    inputs = [v for v in (args.left, args.right, args.calib, args.calib_right) if v is not None]
    stale = []
    for name in OWNED_NAMES:
        if name in written or not isinstance(files.get(name), dict):
            continue
        path = Path(args.out) / name if is_dir else Path(args.out + name)
        try:
            st = path.lstat()
        except OSError:
            continue
        seen = files[name]
        if not stat.S_ISREG(st.st_mode) or (st.st_size, st.st_mtime_ns) != (
            seen.get("size"),
            seen.get("mtime_ns"),
        ):
            continue
        if any(_same_file(path, given) for given in inputs):
            continue
        stale.append(path)
    return stale


def _write_manifest(out_arg: str, out: dict[str, Path], names: dict[str, str]) -> None:
    """Records the files this run wrote, for the next run's :func:`_stale_outputs`. Best
    effort: the outputs are in place already, and without a record the next run removes
    nothing."""
    from .io import atomic_write

    files = {}
    for key, path in out.items():
        try:
            st = path.lstat()
        except OSError:
            continue
        # A link the run wrote through is listed too (it is then no file of the user's to
        # refuse), though never removed as stale: _stale_outputs takes regular files only.
        if stat.S_ISREG(st.st_mode) or stat.S_ISLNK(st.st_mode):
            files[names[key]] = {"size": st.st_size, "mtime_ns": st.st_mtime_ns}
    with (
        contextlib.suppress(OSError, ValueError),
        atomic_write(_manifest_path(out_arg), text=True) as f,
    ):
        f.write(json.dumps({"files": files}, indent=1) + "\n")


def _same_file(a: Path, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _commit(staged: dict[str, Path], out: dict[str, Path], stale: list[Path]) -> None:
    """Renames the staged outputs into place and removes the earlier run's ``stale`` files.
    Called with Ctrl-C and SIGTERM held (:func:`run`): once this starts the run completes,
    and counts as done (a signal that came meanwhile is dropped)."""
    from .io import _fsync_dir as io_fsync_dir

    done: list[Path] = []
    try:
        for key, tmp in staged.items():
            path = out[key]
            if tmp == path:  # a device or a pipe, written directly
                continue
            target = Path(os.path.realpath(path)) if path.is_symlink() else path
            os.replace(tmp, target)
            done.append(target)
            staged[key] = path  # renamed: not a staged file to remove any more
    except BaseException:
        for target in done:  # leave none of a failed run's outputs
            with contextlib.suppress(OSError):
                target.unlink()
        raise
    for path in stale:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
    for folder in {p.parent for p in done}:
        with contextlib.suppress(OSError):
            io_fsync_dir(folder)


def _write_outputs(
    args: argparse.Namespace,
    out: dict[str, Path],
    result: Any,
    rig: dict[str, Any] | None,
    left_img: np.ndarray,
    right_img: np.ndarray,
) -> None:
    """Writes every output of ``out`` (each file atomically)."""
    from . import io
    from ._calib_rule import write_png

    if args.write_rectified:  # after matching: a pair the matcher refuses writes nothing
        write_png(out["left_rectified"], left_img)
        write_png(out["right_rectified"], right_img)
    d = result.disparity
    if args.disparity_format == "pfm":
        io.write_disparity_pfm(out["disparity"], d)  # Middlebury's: +inf where there is none
    elif args.disparity_format == "npy":
        io.write_npy(out["disparity"], d)
    else:
        io.write_disparity_png16(out["disparity"], d)
    if rig is not None:
        from .depth import disparity_to_depth

        assert result.depth is not None
        if args.depth_format == "npy":
            io.write_npy(out["depth"], result.depth)
        elif args.depth_format == "pfm":
            io.write_pfm(out["depth"], result.depth)
        else:
            mm = disparity_to_depth(
                d,
                focal_px=rig["focal_px"],
                baseline_m=rig["baseline_m"],
                doffs_px=rig["doffs_px"],
                dtype=np.uint16,
            )
            io.write_png16(out["depth"], mm)
    if not args.no_preview:
        from .colormap import save_colorized

        save_colorized(out["disparity_preview"], d, quantity="disparity", unit="px", cmap=args.cmap)
        if result.depth is not None:
            save_colorized(
                out["depth_preview"], result.depth, quantity="depth", unit="m", cmap=args.cmap
            )
    if args.ply and rig is not None:
        from .pointcloud import reproject, write_ply

        points = reproject(
            d,
            focal_px=rig["focal_px"],
            baseline_m=rig["baseline_m"],
            doffs_px=rig["doffs_px"],
            cx_px=rig["cx_px"],
            cy_px=rig["cy_px"],
        )
        from .colormap import to_uint8

        # 16-bit images coloured as matched (min-max stretch), not by their high byte.
        write_ply(out["ply"], points, to_uint8(left_img), comment="stereodepth match")


def _print(s: dict[str, Any], left: np.ndarray) -> None:
    kind = "RGB" if left.ndim == 3 else ("16-bit grey" if left.dtype == np.uint16 else "grey")
    p = s["params"]
    lo = s["min_disparity"]
    matcher = f"{s['method']}"
    if s["method"] == "bm":
        matcher += f", {p['cost']}, block {p['block_size']}"
    elif "block_size" in p:
        matcher += f", block {p['block_size']}"
    matcher += f", disparities {lo} to {lo + s['num_disparities'] - 1} px ({s['num_disparities']})"
    rows = [
        ("pair", f"{s['left']}, {s['right']} ({s['width']}x{s['height']} px, {kind})"),
        ("matcher", matcher),
        ("time", f"{s['time_s']:.3g} s"),
        ("density", f"{100 * s['density']:.1f} % of the pixels have a disparity"),
    ]
    dr = s["disparity_range_px"]
    rows.append(("disparity", "none" if dr is None else f"{dr[0]:.4g} to {dr[1]:.4g} px"))
    if s["calibration"] is None:
        rows.append(("depth", "no rig: give --calib, or --focal-px and --baseline-mm"))
    else:
        zr = s["depth_range_m"]
        rows.append(("depth", "none" if zr is None else f"{zr[0]:.4g} to {zr[1]:.4g} m"))
        rows.append(("rig", f"from {s['calibration']}"))
    if s["rectified"]:
        (rw, rh), (ow, oh) = s["raw_size"], s["rectified_size"]
        rows.append(
            (
                "rectified",
                f"yes, {rw}x{rh} to {ow}x{oh} px in {s['rectify_time_s']:.3g} s: "
                "disparity and depth of the rectified left camera",
            )
        )
    for key, path in s["outputs"].items():
        rows.append((key.replace("_", " "), path))
    rows.extend(("removed", path) for path in s["removed"])
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key.ljust(width)}  {value}")
