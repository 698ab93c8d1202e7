"""One pair: read, match, convert, write; failures become a failed record, never an exception."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from .. import _validate as check
from .job import BatchOptions, Pair
from .records import (
    earlier_outputs,
    file_stamp,
    jsonable,
    record_head,
    remove_files,
    settings_of,
)


def _load_pair(pair: Pair) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """(left, right, colours, stamps): the pair for the matcher, the left image as read for the
    point cloud's colours, and the files' size and time, taken before reading them (so that a
    file changed meanwhile is redone next time).

    The images are read by Pillow, which gives colour as RGB. Both must be colour or both
    grey, of the same bit depth: the rule of :func:`stereodepth.block_match`, which refuses a
    mixed pair too; the pair fails with a message that says which image is which."""
    from ..io import read_image

    if not pair.left.is_file():
        raise FileNotFoundError(f"missing left image {pair.left}")
    if not pair.right.is_file():
        raise FileNotFoundError(f"missing right image {pair.right}")
    stamps = {"left": file_stamp(pair.left), "right": file_stamp(pair.right)}
    left, right = read_image(pair.left), read_image(pair.right)
    if left.shape[:2] != right.shape[:2]:
        raise ValueError(
            f"left and right differ in size: {left.shape[1]}x{left.shape[0]} and "
            f"{right.shape[1]}x{right.shape[0]} px"
        )
    colours = left
    if left.ndim != right.ndim:

        def kind(a: np.ndarray) -> str:
            return "colour (RGB)" if a.ndim == 3 else "grey"

        raise ValueError(
            f"the left image is {kind(left)} and the right image {kind(right)}: both must be "
            "colour or both grey (convert one of them; block_match refuses a mixed pair too)"
        )
    if left.dtype != right.dtype:
        raise ValueError(f"left and right differ in bit depth: {left.dtype} and {right.dtype}")
    return left, right, colours, stamps


def _write_map(path: Path, kind: str, array: np.ndarray, fmt: str) -> None:
    from .. import io

    if fmt == "npy":
        io.write_npy(path, array)
    elif fmt == "pfm" and kind == "disparity":
        io.write_disparity_pfm(path, array)  # Middlebury's: +inf where there is none
    elif fmt == "pfm":
        io.write_pfm(path, array)  # a depth of +inf is disparity 0, not a hole
    elif kind == "disparity":
        io.write_disparity_png16(path, array)
    else:
        io.write_png16(path, array)


def process_pair(pair: Pair, options: BatchOptions, threads: int | None = None) -> dict[str, Any]:
    """Computes and writes one pair's outputs; never raises for a bad pair.

    The pair is matched by ``options.method`` (``"bm"``: :class:`stereodepth.StereoMatcher`,
    ``"sgm"``: :class:`stereodepth.SemiGlobalMatcher`) with ``options.matcher``, after
    rectification when ``options.rectification`` is set (a raw ``--calib``): the disparity,
    depth, points and previews are then of the rectified left camera, at the rectified size.

    Returns the pair's record: ``stem``, ``left``, ``right``, ``status`` (``ok`` or
    ``failed``), ``error``, ``time_s``, ``density`` (the fraction of pixels with a
    disparity), ``width``, ``height``, ``outputs``, ``settings``, ``calibration_source``,
    ``calibration_not_used``, ``method``, ``matcher_options``, ``rectified`` and ``removed``
    (the stale files of an earlier run removed). The record is also written, last, as
    ``<stem>.record.json``, for a failed pair too.

    The outputs of an earlier run of the pair (as its record lists them) that this run does
    not write again are removed: all of them when the pair fails (its record then says
    ``failed``), the ``.ply`` of a run with ``--ply`` when this one has none, the files of
    another ``--format``."""
    from .. import __version__, disparity_to_depth
    from ..pointcloud import reproject, write_ply

    t0 = time.perf_counter()
    record = record_head(pair, "failed", options=options)
    earlier = earlier_outputs(pair, options)
    written: set[Path] = set()
    try:
        if pair.problem:
            raise ValueError(pair.problem)
        calib = pair.calibration
        if calib is None or pair.num_disparities is None:
            raise ValueError("no calibration or number of disparities for this pair")
        threads = _task_threads() if threads is None else threads
        left, right, colours, stamps = _load_pair(pair)
        size = getattr(calib, "image_size", None)  # Middlebury's width and height
        if options.rectification is None and size is not None and left.shape[:2] != size[::-1]:
            raise ValueError(
                f"the images are {left.shape[1]}x{left.shape[0]} px and the calibration "
                f"{calib.source} is for {size[0]}x{size[1]} px (its width and height): a "
                "calibration of another resolution gives wrong depths"
            )
        paths = options.output_paths(pair.stem)
        # Before the first file, a record that lists every file this run may write (and those
        # of the run before), in place of the run before's: a job killed before the final
        # record leaves files that the next run knows as its own (a file that no record lists
        # is the user's, not replaced without --force), and a pair that is redone, not done
        # (the run before's "ok" record, left in place, passed a mix of old and new files of
        # the same sizes for a finished pair).
        listed = {k: {"path": str(v)} for k, v in paths.items()}
        listed.update({f"earlier {i}": {"path": str(v)} for i, v in enumerate(sorted(earlier))})
        _write_record(
            options.record_path(pair.stem), {**record, "status": "started", "outputs": listed}
        )
        if options.rectification is not None:
            # The pair as the rectified cameras see it: everything below is in their frame.
            left, right = options.rectification.rectify(left, right, threads)
            colours = left
            if options.write_rectified:
                from .._calib_rule import write_png

                for side, image in (("left", left), ("right", right)):
                    written.add(paths[f"{side}_rectified"])
                    write_png(paths[f"{side}_rectified"], image)
        from .._calib_rule import along_rows, from_rows, matched_along_rows
        from .._methods import compute_disparity, thread_matcher

        matcher = thread_matcher(
            options.method,
            num_disparities=pair.num_disparities,
            **{**options.matcher, "threads": threads},
        )
        # A vertical rig is matched transposed and its disparity turned back (_calib_rule).
        vertical = options.rectification is not None and options.rectification.vertical(threads)
        with matched_along_rows(vertical, left.shape[0]):
            disparity = from_rows(
                vertical, compute_disparity(matcher, *along_rows(vertical, left, right))
            )
        depth = disparity_to_depth(
            disparity,
            focal_px=calib.focal_px,
            baseline_m=calib.baseline_m,
            doffs_px=calib.doffs_px,
            min_depth_m=options.min_depth_m,
            max_depth_m=options.max_depth_m,
            dtype=np.uint16 if options.format == "png16" else np.float32,
            threads=threads,
        )
        written.update(paths.values())
        _write_map(paths["disparity"], "disparity", disparity, options.format)
        _write_map(paths["depth"], "depth", depth, options.format)
        outputs: dict[str, Any] = {}
        if "ply" in paths:
            points = reproject(
                disparity,
                focal_px=calib.focal_px,
                baseline_m=calib.baseline_m,
                cx_px=calib.cx_px,
                cy_px=calib.cy_px,
                doffs_px=calib.doffs_px,
                min_depth_m=options.min_depth_m,
                max_depth_m=options.max_depth_m,
                threads=threads,
            )
            stem = pair.stem.encode("ascii", "backslashreplace").decode("ascii")
            from ..colormap import to_uint8  # 16-bit: coloured as matched, not by the high byte

            if colours.ndim == 3 and options.matcher.get("channel_order") == "bgr":
                # --channel-order bgr: the file's channels are B, G, R (the matcher is told
                # so); a PLY's are red, green, blue (its sky was written red)
                colours = colours[..., ::-1]
            n = write_ply(
                paths["ply"],
                points,
                to_uint8(colours),
                comment=f"stereodepth {__version__}: {stem}, metres",
            )
            outputs["ply_points"] = n
        if "disparity_preview" in paths:
            from ..colormap import save_colorized

            depth_m = (
                depth if depth.dtype != np.uint16 else np.where(depth > 0, depth / 1000.0, np.nan)
            )
            save_colorized(paths["disparity_preview"], disparity, quantity="disparity", unit="px")
            save_colorized(paths["depth_preview"], depth_m, quantity="depth", unit="m")
        density = float(np.count_nonzero(np.isfinite(disparity))) / max(disparity.size, 1)
        record.update(
            status="ok",
            width=int(disparity.shape[1]),
            height=int(disparity.shape[0]),
            density=density,
            inputs=stamps,
            outputs={k: {"path": str(p), "bytes": p.stat().st_size} for k, p in paths.items()},
            settings=settings_of(pair, options),
        )
        if "ply_points" in outputs:
            record["outputs"]["ply"]["points"] = outputs["ply_points"]
        # Stale files go before the new record is written: a job killed in between leaves the
        # old record, which names a missing file, so the pair is redone next time.
        record["removed"] = remove_files(earlier - set(paths.values()))
        record["time_s"] = time.perf_counter() - t0
        _write_record(options.record_path(pair.stem), record)
    except Exception as exc:  # a bad pair is reported, never fatal
        known = (OSError, ValueError, TypeError, MemoryError)
        text = str(exc) if isinstance(exc, known) and str(exc) else f"{type(exc).__name__}: {exc}"
        for key in ("width", "height", "inputs", "outputs", "settings"):
            record.pop(key, None)
        record.update(error=text, density=None, time_s=time.perf_counter() - t0)
        record = record_failure(pair, options, record, written | earlier)
    result: dict[str, Any] = jsonable(record)
    return result


def record_failure(
    pair: Pair, options: BatchOptions, record: dict[str, Any], stale: set[Path] | None = None
) -> dict[str, Any]:
    """Makes ``record`` a failed pair's record on disk: removes the pair's outputs (``stale``,
    else those its earlier record lists), lists them under ``removed`` and writes the record.
    Returns the record; if OUTDIR cannot be written, its error says so too."""
    record = {**record, "status": "failed"}
    try:
        record["removed"] = remove_files(earlier_outputs(pair, options) if stale is None else stale)
        _write_record(options.record_path(pair.stem), record)
    except OSError as exc:  # OUTDIR itself fails: the report still has the record
        record["error"] = f"{record['error']}; and its record could not be written: {exc}"
    return record


def _write_record(path: Path, record: dict[str, Any]) -> None:
    from ..io import atomic_write

    with atomic_write(path, text=True) as fh:
        json.dump(jsonable(record), fh, indent=2, allow_nan=False)
        fh.write("\n")


def _task_threads() -> int | None:
    """Matcher threads for a pair: every core, shared among a Dask worker's threads (None,
    every core, outside a worker)."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return None
    n = getattr(getattr(worker, "state", worker), "nthreads", 1) or 1
    return max(1, check.available_cores() // int(n))
