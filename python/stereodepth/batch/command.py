"""The ``stereodepth batch`` command: its arguments, their checks, and the summary."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from .. import _validate as check
from ..calib import Calibration
from ..cli import key_value_option
from .calibration import resolve_calibration
from .discovery import find_pairs
from .job import FORMATS, BatchOptions, UsageError
from .records import BatchReport
from .runners import run_batch


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
    p.add_argument("input", metavar="INPUT", help="a folder of pairs or a CSV list")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUTDIR",
        help="the folder for the outputs (created if needed)",
    )
    c = p.add_argument_group("calibration (default: each pair's calib.txt or KITTI calib)")
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
        metavar="FILE",
        help="one calibration for every pair: Middlebury calib.txt or KITTI calib",
    )
    o = p.add_argument_group("output")
    o.add_argument(
        "--format",
        choices=sorted(FORMATS),
        default="npy",
        help="npy: float32 (NaN invalid); png16: depth in mm and disparity x 256 "
        "(0 invalid); pfm: float32 (default npy)",
    )
    o.add_argument(
        "--ply", action="store_true", help="also write a coloured binary PLY point cloud in metres"
    )
    o.add_argument("--min-depth-m", type=float, help="depths nearer than this are invalid")
    o.add_argument("--max-depth-m", type=float, help="depths farther than this are invalid")
    o.add_argument("--report", metavar="FILE", help="the JSON report (default OUTDIR/report.json)")
    o.add_argument(
        "--force", action="store_true", help="recompute pairs whose outputs are already complete"
    )
    o.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    m = p.add_argument_group("matcher (stereodepth.block_match)")
    m.add_argument(
        "--num-disparities",
        type=int,
        metavar="N",
        help="disparities searched (default: ndisp from calib.txt; else required)",
    )
    m.add_argument("--min-disparity", type=int, metavar="D", help="smallest disparity searched")
    m.add_argument("--block-size", type=int, metavar="N", help="odd block side")
    m.add_argument("--cost", choices=("census", "sad"), help="matching cost")
    m.add_argument(
        "--option",
        action="append",
        type=key_value_option,
        default=[],
        metavar="KEY=VALUE",
        help="other keyword argument of stereodepth.block_match, repeatable "
        "(e.g. uniqueness_ratio=15, subpixel=false)",
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
        "--workers", type=int, metavar="N", help="start a local Dask cluster of N worker processes"
    )
    r.add_argument(
        "--threads",
        type=int,
        metavar="N",
        help="matcher threads per pair (default: every core; with --workers N, "
        "the cores / N; on a --scheduler cluster, a worker's cores / its threads)",
    )
    p.set_defaults(func=run)


_RESERVED = {
    "num_disparities": "--num-disparities",
    "min_disparity": "--min-disparity",
    "block_size": "--block-size",
    "cost": "--cost",
    "threads": "--threads",
    "return_confidence": "(not available in batch)",
}


def _matcher_options(args: argparse.Namespace) -> dict[str, Any]:
    from ..matching import BlockMatchOptions

    opts: dict[str, Any] = {}
    for key, value in args.option:
        if key in _RESERVED:
            raise UsageError(f"--option {key}: use {_RESERVED[key]}")
        opts[key] = value
    for key in ("min_disparity", "block_size", "cost"):
        if getattr(args, key) is not None:
            opts[key] = getattr(args, key)
    try:  # check them all now, before any pair runs
        BlockMatchOptions(num_disparities=args.num_disparities or 16, **opts)
    except TypeError as exc:
        raise UsageError(f"matcher options: {exc}") from exc
    return opts


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
        source="command line",
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
    if report.interrupted:
        print("interrupted: run the same command again to resume", file=out)
    for rec in report.failed:
        print(f"  failed {rec['stem']}: {rec['error']}", file=out)
    print(f"report: {report_path}", file=out)


def run(args: argparse.Namespace) -> int:
    """Runs ``stereodepth batch``; returns the exit status."""
    from ..io import atomic_write

    if args.num_disparities is not None and args.num_disparities < 1:
        raise UsageError(f"--num-disparities must be an integer >= 1, got {args.num_disparities}")
    given = _given_calibration(args)
    matcher = _matcher_options(args)
    for name in ("min_depth_m", "max_depth_m"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise UsageError(f"--{name.replace('_', '-')} must be a finite number >= 0, got {v}")
    pairs = find_pairs(args.input, pair_names=[tuple(args.pair_names)] if args.pair_names else None)
    pairs = resolve_calibration(
        pairs,
        given=given,
        calib_file=Path(args.calib) if args.calib else None,
        num_disparities=args.num_disparities,
    )
    out_dir = Path(args.output)
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"OUTDIR must be a folder, got the file {out_dir}")
    options = BatchOptions(
        out_dir=out_dir,
        format=args.format,
        ply=args.ply,
        matcher=matcher,
        min_depth_m=args.min_depth_m,
        max_depth_m=args.max_depth_m,
        force=args.force,
    )
    report = run_batch(
        pairs,
        options,
        scheduler=args.scheduler,
        workers=args.workers,
        threads=args.threads,
        progress=not args.quiet and sys.stderr.isatty(),
    )
    report_path = Path(args.report) if args.report else out_dir / "report.json"
    data = report.as_dict()
    data["input"] = str(args.input)
    data["output"] = str(out_dir)
    with atomic_write(report_path, text=True) as fh:
        json.dump(data, fh, indent=2, allow_nan=False)
        fh.write("\n")
    if not args.quiet:
        print_summary(report, report_path)
    elif report.failed:
        for rec in report.failed:
            print(f"stereodepth batch: failed {rec['stem']}: {rec['error']}", file=sys.stderr)
    if report.interrupted:
        print("stereodepth batch: interrupted", file=sys.stderr)
    return report.exit_status
