"""The ``stereodepth batch`` command: its arguments, their checks, and the summary."""

from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from .. import _calib_rule
from .. import _validate as check
from .._extras import require
from .._methods import METHODS, check_method
from ..calib import Calibration
from ..cli import (
    KeyValueOnce,
    escape_line_breaks,
    key_value_option,
    one_line,
    path_arg,
    terminated,
)
from .calibration import (
    COMMAND_LINE,
    BatchRectifier,
    calibration_note,
    raw_rectification,
    resolve_calibration,
)
from .discovery import check_pair_names, discover
from .job import FORMATS, BatchOptions, Pair, UsageError
from .records import BatchReport
from .runners import LOCK_NAME, check_runner, run_batch


def register(subparsers: Any) -> None:
    """Adds ``stereodepth batch`` to the command's subparsers."""
    p = subparsers.add_parser(
        "batch",
        help="disparity, depth and point clouds for many stereo pairs (here or on Dask)",
        description=(
            "Computes the disparity and depth (and with --ply a coloured point cloud) of every "
            "stereo pair in INPUT: KITTI image_2/image_3 folders, Middlebury scene folders "
            "(im0, im1, calib.txt), pairs named left/right, or a CSV list of left,right[,stem]. "
            "Pairs that fail are reported and skipped; outputs are written atomically; "
            "running the same command again resumes. Exit status 1 when a pair failed."
        ),
    )
    # One line for an argparse error too, like every other error of the command.
    p.error = _one_line_error(p)
    p.add_argument("input", type=path_arg, metavar="INPUT", help="a folder of pairs or a CSV list")
    p.add_argument(
        "-o",
        "--output",
        type=path_arg,
        required=True,
        metavar="OUTDIR",
        help="the folder for the outputs (created if needed)",
    )
    c = p.add_argument_group(
        "calibration (the first given wins: these flags, --calib, each pair's own file)"
    )
    c.add_argument("--focal-px", type=float, help="focal length in pixels")
    c.add_argument("--baseline-mm", type=float, help="baseline in millimetres")
    c.add_argument(
        "--doffs-px",
        type=float,
        default=0.0,
        help="principal point offset cx_right - cx_left in px (Middlebury doffs)",
    )
    c.add_argument(
        "--cx-px", type=float, help="left principal point x for --ply (default: the image centre)"
    )
    c.add_argument("--cy-px", type=float, help="left principal point y for --ply")
    c.add_argument(
        "--calib",
        type=path_arg,
        metavar="FILE",
        help="one calibration for every pair: Middlebury calib.txt or KITTI calib (rectified "
        "pairs: matched as given), or a raw calibration (OpenCV FileStorage YAML/XML/JSON, Kalibr "
        "camchain, ROS camera_info): every pair is rectified first and the depth is in the "
        "rectified left camera's frame",
    )
    _calib_rule.add_raw_flags(c)
    o = p.add_argument_group("output")
    o.add_argument(
        "--format",
        choices=sorted(FORMATS),
        default="npy",
        help="npy: float32 (NaN invalid); png16: depth in mm and disparity x 256 "
        "(0 invalid; depth 1 for 1 mm and nearer, 65535 for 65.535 m and farther); pfm: "
        "float32 (disparity +inf invalid, as Middlebury; depth NaN) (default npy)",
    )
    o.add_argument(
        "--ply", action="store_true", help="also write a coloured binary PLY point cloud in metres"
    )
    o.add_argument(
        "--preview",
        action="store_true",
        help="also write colour previews of the disparity and the depth, with colour bars "
        "(S.disparity.preview.png, S.depth.preview.png; needs matplotlib, the plot extra)",
    )
    o.add_argument(
        "--write-rectified",
        action="store_true",
        help="with a raw --calib: also write each rectified pair as S.left-rectified.png and "
        "S.right-rectified.png",
    )
    o.add_argument("--min-depth-m", type=float, help="depths nearer than this are invalid")
    o.add_argument("--max-depth-m", type=float, help="depths farther than this are invalid")
    o.add_argument(
        "--report",
        type=path_arg,
        metavar="FILE",
        help="the JSON report (default OUTDIR/report.json); its folder must exist",
    )
    o.add_argument(
        "--force",
        action="store_true",
        help="recompute pairs whose outputs are already complete, and replace outputs of the "
        "same names made from other images, or a report file that no batch job wrote (refused "
        "without it)",
    )
    o.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    m = p.add_argument_group(
        "matcher (bm: stereodepth.block_match; sgm: stereodepth.semi_global_match)"
    )
    m.add_argument(
        "--method",
        choices=METHODS,
        default="bm",
        help="bm: block matching (default); sgm: semi-global matching (more accurate, slower)",
    )
    m.add_argument(
        "--num-disparities",
        type=int,
        metavar="N",
        help="disparities searched (default: ndisp of the Middlebury calib.txt that gives the "
        "rig; required with KITTI files, with --focal-px and with a raw --calib)",
    )
    m.add_argument("--min-disparity", type=int, metavar="D", help="smallest disparity searched")
    from .._methods import block_sizes_text
    from ..matching import MAX_BLOCK_SIZE

    costs, sgm_sizes = block_sizes_text()
    m.add_argument(
        "--block-size",
        type=int,
        metavar="N",
        help=f"block side, by method: bm an odd number, {costs}; sgm {sgm_sizes} only",
    )
    m.add_argument("--cost", choices=tuple(MAX_BLOCK_SIZE), help="matching cost (bm only)")
    m.add_argument(
        "--option",
        action=KeyValueOnce,
        type=key_value_option,
        default=[],
        metavar="KEY=VALUE",
        help="other keyword argument of the method's matcher, repeatable "
        "(e.g. uniqueness_ratio=15, subpixel=false; sgm: p1=40, p2=500, paths=8)",
    )
    m.add_argument(
        "--channel-order",
        choices=("rgb", "bgr"),
        help="the order of the colour channels as read: Pillow reads image files as RGB, so "
        "bgr only for files whose channels were stored swapped (default rgb)",
    )
    m.add_argument(
        "--pair-names",
        nargs=2,
        metavar=("LEFT", "RIGHT"),
        help="the tokens that name a left and a right image (default: im0 im1, left right)",
    )
    r = p.add_argument_group("where it runs (default: this process)")
    r.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="an existing dask.distributed scheduler, tcp://HOST:PORT",
    )
    r.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="start a local Dask cluster of N worker processes (at most the cores)",
    )
    r.add_argument(
        "--threads",
        type=int,
        metavar="N",
        help="matcher threads per pair (default: every core; with --workers N, "
        "the cores / N; on a --scheduler cluster, a worker's cores / its threads)",
    )
    p.set_defaults(func=run)


#: --option keys that have their own flag, or (None) that batch does not offer.
_RESERVED: dict[str, str | None] = {
    "num_disparities": "--num-disparities",
    "min_disparity": "--min-disparity",
    "block_size": "--block-size",
    "cost": "--cost",
    "threads": "--threads",
    "channel_order": "--channel-order",
    "return_confidence": None,
    "isa": None,
}
_FLAGS = {"min_disparity": "--min-disparity", "block_size": "--block-size", "cost": "--cost"}


def _failure(record: dict[str, Any]) -> str:
    """A failed pair's stem and error on one line, whatever they hold (a file or folder name
    with a line break in it, printed as it was, over two lines); the record keeps both as
    they were."""
    return f"{escape_line_breaks(record['stem'])}: {escape_line_breaks(record['error'])}"


def _one_line_error(parser: argparse.ArgumentParser) -> Callable[[str], NoReturn]:
    """argparse's error(), in one line (``stereodepth batch: error: ...``, exit status 2)
    without the usage block."""

    def error(message: str) -> NoReturn:
        parser.exit(2, f"{parser.prog}: error: {message}\n")

    return error


#: For each method, the options whose limits the others' depend on: checked first, then
#: given along with each later one, so that an error names the option at fault.
_BASES = {"bm": ("cost",), "sgm": ("block_size", "paths", "p1")}


def _matcher_options(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments of ``--method``'s matcher from --option and the matcher flags,
    each checked now, before any pair runs, by the matcher's own rules, with an error that
    names what the user typed; an option of the other method says so."""
    from .._methods import METHOD_NAMES, METHODS, matcher_class, matcher_keywords, options_class

    method = args.method
    known = matcher_keywords(method)
    names = ", ".join(k for k in known if k not in _RESERVED)
    this = f"--method {method} ({METHOD_NAMES[method]})"

    def not_an_option(typed: str, key: str) -> UsageError:
        owners = [m for m in METHODS if m != method and key in matcher_keywords(m)]
        if owners:
            return UsageError(
                f"{typed}: an option of --method {owners[0]}; {this} has no option {key!r} "
                f"(its options: {names})"
            )
        return UsageError(f"{typed}: {this} has no option {key!r} (its options: {names})")

    opts: dict[str, Any] = {}
    typed: dict[str, str] = {}
    for key, value in args.option:
        if key in _RESERVED and (key in known or _RESERVED[key] is None):
            flag = _RESERVED[key]
            raise UsageError(
                f"--option {key}: use {flag}" if flag else f"--option {key}: not available in batch"
            )
        if key not in known:
            raise not_an_option(f"--option {key}", key)
        opts[key] = value
        typed[key] = f"--option {key}"
    for key, flag in _FLAGS.items():
        if getattr(args, key) is not None:
            if key not in known:
                raise not_an_option(flag, key)
            opts[key] = getattr(args, key)
            typed[key] = f"{flag} {getattr(args, key)}"
    nd = args.num_disparities or 16
    checker = options_class(method)
    try:
        checker(num_disparities=nd)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"--num-disparities {nd}: {exc}") from exc
    checked = set(inspect.signature(checker.__init__).parameters)
    try:  # together first: p1=300 alone is refused (the default p2 is 250), with p2=700 not
        checker(num_disparities=nd, **{k: v for k, v in opts.items() if k in checked})
        at_fault: list[str] = []
    except (TypeError, ValueError) as exc:
        # The matchers' messages start with the parameter at fault (p2 for p1=500 p2=10,
        # which checking p1 alone against the default p2 blamed on p1); the longest name
        # first, so that p2_step is not read as p2.
        culprit = next(
            (
                k
                for k in sorted(opts, key=len, reverse=True)
                if k in checked and str(exc).startswith(k)
            ),
            None,
        )
        if culprit is not None:
            raise UsageError(f"{typed[culprit]}: {exc}") from exc
        at_fault = list(opts)
    bases = [k for k in _BASES[method] if k in at_fault]
    context: dict[str, Any] = {}
    for key in [*bases, *sorted(k for k in at_fault if k not in bases)]:
        if key in checked:
            try:
                checker(num_disparities=nd, **{**context, key: opts[key]})
            except (TypeError, ValueError) as exc:
                raise UsageError(f"{typed[key]}: {exc}") from exc
        if key in bases:
            context[key] = opts[key]
    if args.channel_order is not None:
        if "channel_order" not in known:
            raise UsageError(f"--channel-order: {this} has no channel_order")
        opts["channel_order"] = args.channel_order
    try:  # all together, as each pair will make its matcher
        matcher_class(method)(num_disparities=nd, threads=1, **opts)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"{this} options: {exc}") from exc
    return opts


def sample_bits(path: Path) -> int | None:
    """8 or 16: the bit depth :func:`stereodepth.io.read_image` gives the image at ``path``,
    from its header alone; None when the header does not say (a missing or unreadable file,
    floating-point or 16-bit colour samples, which reading the pair refuses with its own
    message)."""
    from ..io import _sample_dtype

    dtype = _sample_dtype(path)
    return None if dtype is None else 8 * dtype.itemsize


def _check_intensity_range(pairs: Sequence[Pair], matcher: dict[str, Any]) -> None:
    """``--option intensity_range`` applies to 16-bit images only (an 8-bit pair given it
    fails): refused before the first pair when any pair to be matched has an 8-bit left image,
    told by each left image's header (:func:`sample_bits`; a folder mixing 8- and 16-bit pairs
    is refused, naming how many are 8-bit and the first). A header that does not say is left
    to the pair, whose read gives its own error."""
    value = matcher.get("intensity_range")
    if value is None:
        return
    runnable = [p for p in pairs if not p.problem]
    eight = [p for p in runnable if sample_bits(p.left) == 8]
    if not eight:
        return
    typed = ",".join(map(str, value)) if isinstance(value, (tuple, list)) else str(value)
    n, m, first = len(eight), len(runnable), eight[0]
    where = f"{first.stem}: {first.left}" if n == 1 else f"the first: {first.stem}, {first.left}"
    found = (
        "the pair is 8-bit"
        if m == 1
        else f"all {m} pairs are 8-bit"
        if n == m
        else f"{n} of the {m} pairs {'is' if n == 1 else 'are'} 8-bit"
    )
    fix = "drop it" if n == m else "drop it, or run it on the 16-bit pairs alone"
    raise UsageError(
        f"--option intensity_range={typed} applies to 16-bit images only (8-bit ones are "
        f"matched as they are), and {found} ({where}): {fix}"
    )


def _check_search_range(pairs: Sequence[Pair], options: BatchOptions) -> None:
    """``--min-disparity`` must leave each pair some disparity inside its images (the
    matchers' rule: pixel x is matched at x - d, so only -(W - 1) .. W - 1 can be): refused
    before the first pair, naming the first pair out of reach, rather than failing every pair.
    W is bounded by the larger side of each left image, told by its header (an EXIF quarter
    turn or a vertical rig matches along the other side), so a job this refuses could match
    no pixel at all; a range between the two sides is left to the pair's own error, and so is
    a header that does not say."""
    from ..io import _header_size
    from ..matching import search_reaches

    low = int(options.matcher.get("min_disparity", 0))
    if low == 0:
        return  # 0 .. n - 1 always reaches into an image at least 1 px across
    for p in pairs:
        if p.problem or p.num_disparities is None:
            continue
        size = _header_size(p.left)
        if size is None:
            continue
        extent = max(size)
        high = low + p.num_disparities - 1
        if not search_reaches(low, p.num_disparities, extent):
            raise UsageError(
                f"--min-disparity {low}: pair {p.stem!r} would search disparities {low} to "
                f"{high}, none of which lies inside its {size[0]}x{size[1]} px images: only "
                f"{-(extent - 1)} to {extent - 1} can be matched along their longer side, and "
                "every pixel would be NaN"
            )


def _check_report_replaceable(report: Path, force: bool) -> None:
    """An existing file at the report's path is replaced only when it reads as a batch report
    (a JSON object with a report's "stereodepth", "runner" and "counts"), or with ``--force``:
    a report.json of the user's in OUTDIR was replaced without a word, where a file of theirs
    at a pair's output name is refused (runners._refuse_replacing_files_of_no_record)."""
    if force or not report.is_file():
        return
    try:
        with report.open("rb") as f:
            data = json.loads(f.read())
    except (OSError, ValueError):  # (UnicodeDecodeError is a ValueError)
        data = None
    if isinstance(data, dict) and {"stereodepth", "runner", "counts"} <= data.keys():
        return
    raise UsageError(
        f"--report {report}: an existing file that is not a batch report (a file of yours?): "
        "move it, give --report another file, or give --force to replace it"
    )


def _raw_rectification(
    args: argparse.Namespace,
) -> tuple[BatchRectifier, Calibration] | None:
    """The rectifier and rectified rig of a raw --calib file, None for none or a rectified
    one; the flags that go with a raw file checked (the rule of ``stereodepth match``)."""
    if args.calib is None:
        try:
            _calib_rule.check_without_calib(**_calib_rule.flags(args))
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        return None
    return raw_rectification(
        args.calib,
        **_calib_rule.flags(args),
        threads=args.threads,
    )


def _rectify_note(raw: tuple[BatchRectifier, Calibration] | None) -> str | None:
    if raw is None:
        return None
    w, h = raw[0].image_size
    return (
        f"--calib {raw[0].source} is a raw calibration: every pair ({w}x{h} px) is rectified "
        "before matching; disparity, depth and points are of the rectified left camera"
    )


def _given_calibration(args: argparse.Namespace) -> Calibration | None:
    if args.focal_px is None and args.baseline_mm is None:
        for name in ("cx_px", "cy_px"):
            if getattr(args, name) is not None:
                raise UsageError(
                    f"--{name.replace('_', '-')} goes with --focal-px and --baseline-mm"
                )
        if args.doffs_px:
            raise UsageError("--doffs-px goes with --focal-px and --baseline-mm")
        return None
    if args.focal_px is None or args.baseline_mm is None:
        raise UsageError("give both --focal-px and --baseline-mm")
    if args.calib is not None:
        raise UsageError("give --focal-px and --baseline-mm, or --calib, not both")
    return Calibration(
        focal_px=check.positive("--focal-px", args.focal_px),
        baseline_m=check.positive("--baseline-mm", args.baseline_mm) / 1000.0,
        doffs_px=check.finite("--doffs-px", args.doffs_px),
        cx_px=None if args.cx_px is None else check.finite("--cx-px", args.cx_px),
        cy_px=None if args.cy_px is None else check.finite("--cy-px", args.cy_px),
        source=COMMAND_LINE,
    )


def _check_depth_range(args: argparse.Namespace) -> None:
    """The rule of :func:`stereodepth.disparity_to_depth`, in the flags' names."""
    lo, hi = args.min_depth_m, args.max_depth_m
    if lo is not None and not (math.isfinite(lo) and lo >= 0):
        raise UsageError(f"--min-depth-m must be a finite number >= 0, got {lo}")
    if hi is not None and not (math.isfinite(hi) and hi > 0):
        raise UsageError(f"--max-depth-m must be a finite number > 0, got {hi}")
    if lo is not None and hi is not None and hi < lo:
        raise UsageError(
            f"--max-depth-m must be >= --min-depth-m, got --min-depth-m {lo:g} and "
            f"--max-depth-m {hi:g}"
        )


def _writable_folder(path: Path, what: str) -> None:
    """Raises UsageError unless ``path`` is, or can be created as, a folder we may write in."""
    if path.exists() and not path.is_dir():
        raise UsageError(f"{what} must be a folder, got the file {path}")
    existing = path.absolute()
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise UsageError(f"{what} {path} cannot be created: {existing} is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UsageError(f"{what} {path}: cannot write in {existing}")


def _report_path(args: argparse.Namespace, out_dir: Path) -> Path:
    """Where the report goes, checked before any work: OUTDIR/report.json, or --report FILE
    in a folder that exists (or in OUTDIR), and not a read-only file (which failed the job
    with exit 1 after every pair had been matched)."""
    from ..io import _refuse_read_only

    if args.report is None:
        report = out_dir / "report.json"
        try:  # (a link is written through: its target)
            _refuse_read_only(Path(os.path.realpath(report)), report)
        except PermissionError as exc:
            raise UsageError(f"-o {out_dir}: {exc.strerror} (or give --report FILE)") from None
        return report
    report = Path(args.report)
    if report.is_dir():
        raise UsageError(f"--report must be a file, got the folder {report}")
    folder = report.parent
    if folder.resolve() != out_dir.resolve():
        if not folder.is_dir():
            from ..io import no_folder_reason

            why = no_folder_reason(report)
            raise UsageError(f"--report {report}: {why}")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise UsageError(f"--report {report}: cannot write in {folder}")
    try:
        _refuse_read_only(Path(os.path.realpath(report)), report)
    except PermissionError as exc:
        raise UsageError(f"--report {report}: {exc.strerror}") from None
    return report


def _check_report_is_its_own(
    report: Path,
    pairs: Sequence[Pair],
    options: BatchOptions,
    job_inputs: Sequence[tuple[str, str | None]] = (),
) -> None:
    """The report must not be a file a pair reads or writes, nor the lock, nor one of the
    job's own inputs (``job_inputs``: flag and value, such as the CSV list given as INPUT or
    the ``--calib`` file, which ``--report`` used to overwrite)."""
    r = report.resolve()
    for flag, value in job_inputs:
        if value is not None and Path(value).is_file() and Path(value).resolve() == r:
            raise UsageError(f"--report {report}: that is {flag} {value}; give another file")
    in_out_dir = r.parent == options.out_dir.resolve()
    if in_out_dir and r.name == LOCK_NAME:
        raise UsageError(f"--report {report}: that is the lock file of batch jobs")
    for p in pairs:
        if in_out_dir and r.name in options.owned_names(p.stem):
            raise UsageError(
                f"--report {report}: pair {p.stem!r} writes that file; give the report another name"
            )
        for f in (p.left, p.right, p.calib_file):
            if f is not None and f.resolve() == r:
                raise UsageError(f"--report {report}: that is an input of pair {p.stem!r}")


def _check_outputs_are_not_inputs(
    pairs: Sequence[Pair], options: BatchOptions, calib_files: Sequence[str | None]
) -> None:
    """No file a pair may write or remove as stale (:meth:`BatchOptions.owned_names`) is an
    input of any pair or the job (images, calibration files): a CSV list naming
    ``OUTDIR/S.left-rectified.png`` as S's left image had it overwritten by its rectification;
    and every such name fits in a file name."""
    inputs: dict[Path, str] = {}
    for c in calib_files:
        if c is not None:
            inputs[Path(c).resolve()] = c
    for p in pairs:
        for f in (p.left, p.right, p.calib_file):
            if f is not None:
                inputs[f.resolve()] = str(f)
    from ..io import NAME_MAX_BYTES

    out_dir = options.out_dir.resolve()
    for p in pairs:
        longest = max(options.owned_names(p.stem), key=lambda n: len(os.fsencode(n)))
        if len(os.fsencode(longest)) > NAME_MAX_BYTES:
            # Its folders' names joined: the pair was matched, then failed to write every
            # file, its record included ([Errno 36]), on every run.
            raise UsageError(
                f"pair {p.stem[:40]!r}...: its output names, such as {longest[-40:]!r}, would "
                f"be longer than a file name may be ({NAME_MAX_BYTES} bytes): give it a "
                "shorter stem in a CSV list"
            )
        for name in sorted(options.owned_names(p.stem)):
            hit = inputs.get(out_dir / name)
            if hit is not None:
                raise UsageError(
                    f"pair {p.stem!r} would write {options.out_dir / name}, which is the input "
                    f"{hit}: choose another OUTDIR (-o)"
                )


def print_summary(report: BatchReport, report_path: Path, file: Any = None) -> None:
    out = file or sys.stdout
    c = report.counts
    n = len(report.pairs)
    words = [f"{c['ok']} done"]
    if c["skipped"]:
        words.append(f"{c['skipped']} already done")
    if c["failed"]:
        words.append(f"{c['failed']} failed")
    if c["cancelled"]:
        words.append(f"{c['cancelled']} cancelled")
    rate = f"{c['ok'] / report.elapsed_s:.2f} pairs/s, " if c["ok"] and report.elapsed_s else ""
    print(
        f"{n} pair{'s' if n != 1 else ''}: {', '.join(words)} in {report.elapsed_s:.1f} s "
        f"({rate}{report.runner})",
        file=out,
    )
    if report.interrupted and report.force and c["cancelled"]:
        # The same command would start over; without --force the pairs it did not reach are
        # skipped (their earlier outputs are complete): no command resumes a forced run.
        print(
            "interrupted: --force redoes every pair, so the same command starts over; without "
            "--force, the pairs cancelled keep the outputs of the run before",
            file=out,
        )
    elif report.interrupted:
        print("interrupted: run the same command again to resume", file=out)
    if report.error:
        print(f"stopped: {one_line(report.error)}: run the same command again to resume", file=out)
    for rec in report.failed:
        print(f"  failed {_failure(rec)}", file=out)
    removed = sum(len(rec.get("removed") or ()) for rec in report.pairs)
    if removed:
        print(
            f"  removed {removed} stale output file{'s' if removed != 1 else ''} of earlier "
            "runs (listed in the pairs' records)",
            file=out,
        )
    print(f"report: {report_path}", file=out)


def _show_summary(report: BatchReport, report_path: Path) -> None:
    """Prints the summary on stdout, once every output and the report are written: a summary
    that cannot be printed loses no work, so the exit status stays the report's (it was 1,
    and a job whose pairs were all done looked failed). The reader gone (a broken pipe:
    ``stereodepth batch ... | head -1``) ends it quietly, as it ends ``match``'s; stdout
    closed (``>&-``) or unwritable (full) is said in one line on stderr, naming the report.
    (``match`` fails instead: its summary is printed before its outputs are in place.)"""
    why: str | None = "stdout is closed"  # Python has no sys.stdout: print() writes nothing
    if sys.stdout is not None:
        try:
            print_summary(report, report_path)
            sys.stdout.flush()
            return
        except BrokenPipeError:
            why = None
        except OSError as exc:
            why = exc.strerror or str(exc)
        # What is still buffered would fail again at exit ("Exception ignored ..."): it goes
        # to /dev/null instead, as cli.main does after a broken pipe.
        with contextlib.suppress(OSError, ValueError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, sys.stdout.fileno())
            finally:
                os.close(devnull)
    if why is not None:
        print(
            f"stereodepth batch: note: cannot print the summary ({why}); the report, "
            f"{report_path}, holds every pair's status",
            file=sys.stderr,
        )


def run(args: argparse.Namespace) -> int:
    """Runs ``stereodepth batch``; returns the exit status.

    Everything that no pair could get past is checked first, before any pair runs or any
    file is written: the options, the optional extras, the output locations, then the pairs
    and their calibration."""
    from ..io import atomic_write

    if args.num_disparities is not None and args.num_disparities < 1:
        raise UsageError(f"--num-disparities must be an integer >= 1, got {args.num_disparities}")
    given = _given_calibration(args)
    check_method(args.method, "--method")
    matcher = _matcher_options(args)
    _check_depth_range(args)
    pair_names = [tuple(args.pair_names)] if args.pair_names else None
    if pair_names:
        check_pair_names(pair_names, "--pair-names")
    progress = not args.quiet and sys.stderr.isatty()
    check_runner(
        scheduler=args.scheduler, workers=args.workers, threads=args.threads, progress=progress
    )
    require("PIL.Image", "reading images")
    if args.preview:
        require("matplotlib", "--preview")
    raw = _raw_rectification(args)
    out_dir = Path(args.output)
    _writable_folder(out_dir, "OUTDIR")
    report_path = _report_path(args, out_dir)

    found = discover(args.input, pair_names=pair_names, exclude=[out_dir])
    pairs = resolve_calibration(
        found.pairs,
        given=given,
        calib_file=Path(args.calib) if args.calib else None,
        num_disparities=args.num_disparities,
        calib_rig=None if raw is None else raw[1],
    )
    options = BatchOptions(
        out_dir=out_dir,
        format=args.format,
        ply=args.ply,
        preview=args.preview,
        matcher=matcher,
        min_depth_m=args.min_depth_m,
        max_depth_m=args.max_depth_m,
        force=args.force,
        method=args.method,
        rectification=None if raw is None else raw[0],
        write_rectified=args.write_rectified,
    )
    _check_report_is_its_own(
        report_path,
        pairs,
        options,
        [("INPUT", args.input), ("--calib", args.calib), ("--calib-right", args.calib_right)],
    )
    _check_report_replaceable(report_path, args.force)
    _check_outputs_are_not_inputs(pairs, options, [args.calib, args.calib_right])
    _check_intensity_range(pairs, options.matcher)
    _check_search_range(pairs, options)
    if args.format == "png16":  # KITTI's disparity PNG holds at most 65535 / 256 px
        lowest = int(options.matcher.get("min_disparity", 0))
        if lowest < 0:  # and no negative disparities: they would be written as holes
            raise UsageError(
                f"--format png16 holds no negative disparities (KITTI's d x 256, 0 for none), "
                f"and --min-disparity {lowest} searches them: they would be written as holes; "
                "use --format pfm or npy"
            )
        for pair in pairs:
            if pair.num_disparities is not None and lowest + pair.num_disparities > 256:
                raise UsageError(
                    f"--format png16 holds disparities up to 255.996 px, and {pair.stem} "
                    f"searches up to {lowest + pair.num_disparities - 1} px (--min-disparity "
                    "+ --num-disparities - 1): use --format pfm or npy"
                )
    notes = found.skipped_text(limit=len(found.skipped))
    calib_notes = [n for n in (calibration_note(pairs), _rectify_note(raw)) if n]
    notes.extend(calib_notes)
    if not args.quiet:
        shown = found.skipped_text() + calib_notes
        for note in shown:
            print(f"stereodepth batch: note: {note}", file=sys.stderr)
    report = run_batch(
        pairs,
        options,
        scheduler=args.scheduler,
        workers=args.workers,
        threads=args.threads,
        progress=progress,
        notes=notes,
    )
    data = report.as_dict()
    if report.interrupted and terminated():  # SIGTERM: stopped as by Ctrl-C, exit 143
        data["exit_status"] = 143
    data["input"] = str(args.input)
    data["output"] = str(out_dir)
    try:
        with atomic_write(report_path, text=True) as fh:
            json.dump(data, fh, indent=2, allow_nan=False)
            fh.write("\n")
    except OSError as exc:
        print(
            f"stereodepth batch: error: cannot write the report {report_path}: "
            f"{exc.strerror or exc} (the pairs' records are in {out_dir})",
            file=sys.stderr,
        )
        return 1
    if not args.quiet:
        _show_summary(report, report_path)
    elif report.failed:
        for rec in report.failed:
            print(f"stereodepth batch: failed {_failure(rec)}", file=sys.stderr)
    if report.error:
        print(
            f"stereodepth batch: error: {one_line(report.error)}: run the same command again "
            "to resume",
            file=sys.stderr,
        )
    if report.interrupted and terminated():
        return 143  # stereodepth's main says "terminated"
    if report.interrupted:
        print("stereodepth batch: interrupted", file=sys.stderr)
    return report.exit_status
