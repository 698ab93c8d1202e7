"""Per-pair records (``<stem>.record.json``), resuming from them, stale outputs, and the job's
report."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .job import STATUSES, BatchOptions, Pair, read_record


def file_stamp(p: Path) -> dict[str, Any]:
    """An input image's identity for resuming: the file it is (links followed, as an absolute
    path), its size and time. The path as given depended on the folder the job ran from and
    on the runner (a ``--scheduler`` job's are absolute), so the same job run again with
    INPUT spelled otherwise, or resumed here after its Dask cluster went away, redid every
    pair."""
    st = p.stat()
    return {"path": os.path.realpath(p), "bytes": st.st_size, "mtime_ns": st.st_mtime_ns}


def settings_of(pair: Pair, options: BatchOptions) -> dict[str, Any]:
    """Everything the outputs of a pair depend on (compared when resuming)."""
    from .. import __version__

    if pair.calibration is None:
        raise ValueError(f"pair {pair.stem} has no calibration")
    return {
        "stereodepth": __version__,
        "format": options.format,
        "ply": options.ply,
        "preview": options.preview,
        "min_depth_m": options.min_depth_m,
        "max_depth_m": options.max_depth_m,
        "num_disparities": pair.num_disparities,
        "method": options.method,
        "matcher": matcher_options(options),
        "calibration": {k: v for k, v in pair.calibration.as_dict().items() if k != "source"},
        # The size the calibration is for: a file edited to another size than the images'
        # was passed on a rerun as "already done", where a first run refuses the pair.
        "calibration_size": pair.calibration.image_size,
        "rectification": None if options.rectification is None else options.rectification.as_dict(),
        "write_rectified": options.write_rectified,
    }


def matcher_options(options: BatchOptions) -> dict[str, Any]:
    """The matcher options a job was given (``--option`` and the matcher flags), sorted; the
    number of disparities is each pair's, the threads the runner's."""
    return {k: v for k, v in sorted(options.matcher.items()) if k != "threads"}


def completed_record(pair: Pair, options: BatchOptions) -> dict[str, Any] | None:
    """The record of an earlier run when it is complete and made with the same inputs and
    settings, else None."""
    if pair.problem or pair.calibration is None:
        return None
    record = read_record(options.record_path(pair.stem))
    if record is None:
        return None
    try:
        if record.get("status") != "ok" or record.get("settings") != jsonable(
            settings_of(pair, options)
        ):
            return None
        inputs = record["inputs"]
        if inputs != {"left": file_stamp(pair.left), "right": file_stamp(pair.right)}:
            return None
        expected = options.output_paths(pair.stem)
        if set(record["outputs"]) != set(expected):
            return None
        for key, p in expected.items():
            if record["outputs"][key]["bytes"] != p.stat().st_size:
                return None
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return dict(record)


def jsonable(value: Any) -> Any:
    """JSON-safe: non-finite floats as None, tuples as lists, paths as strings."""
    if isinstance(value, np.generic):  # first: numpy's float32 NaN is not a Python float
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def record_head(
    pair: Pair, status: str, error: str | None = None, options: BatchOptions | None = None
) -> dict[str, Any]:
    """The fields every record of a pair starts with; the rest are filled in as known. With
    the job's ``options``: the matcher (``method``, ``matcher_options``) and whether the pair
    is rectified before matching (``rectified``)."""
    head: dict[str, Any] = {
        "stem": pair.stem,
        "left": str(pair.left),
        "right": str(pair.right),
        "status": status,
        "error": error,
        "time_s": None,
        "density": None,
        "calibration_source": None if pair.calibration is None else pair.calibration.source,
        "calibration_not_used": str(pair.calib_file) if pair.calib_file_unused else None,
    }
    if options is not None:
        head["method"] = options.method
        head["matcher_options"] = matcher_options(options)
        head["rectified"] = options.rectification is not None
    return head


def earlier_outputs(pair: Pair, options: BatchOptions) -> set[Path]:
    """The files an earlier run of this pair wrote, as its record lists them, in OUTDIR: only
    the names this pair owns (:meth:`BatchOptions.owned_names`) count, whatever else a record
    edited by hand may say."""
    record = read_record(options.record_path(pair.stem))
    if record is None:
        return set()
    try:
        listed = [Path(v["path"]) for v in record["outputs"].values()]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return set()
    owned = options.owned_names(pair.stem)
    return {options.out_dir / p.name for p in listed if p.name in owned}


def remove_files(paths: set[Path]) -> list[str]:
    """Removes the files that exist among ``paths``; returns their paths, sorted. A folder at
    one of them is no file of ours and is left (unlink raised IsADirectoryError there, and the
    files after it stayed); so is a read-only file (a result the user made read-only to keep,
    which io's writers refuse to replace: a pair that failed on it removed it)."""
    from ..io import _is_read_only

    removed = []
    for p in sorted(paths):
        if (p.is_dir() and not p.is_symlink()) or _is_read_only(p):
            continue
        try:
            p.unlink()
        except FileNotFoundError:
            continue
        removed.append(str(p))
    return removed


@dataclass
class BatchReport:
    """What a job did: one record per pair, in input order, and the totals."""

    pairs: list[dict[str, Any]]
    runner: str
    elapsed_s: float
    interrupted: bool = False
    started: str = ""
    removed_temp_files: int = 0
    notes: list[str] = field(default_factory=list)
    method: str = "bm"
    matcher_options: dict[str, Any] = field(default_factory=dict)
    rectification: dict[str, Any] | None = None
    force: bool = False  # --force: every pair was to be redone
    error: str | None = None  # why the job stopped short (the Dask cluster failed it)

    @property
    def counts(self) -> dict[str, int]:
        return {s: sum(1 for p in self.pairs if p["status"] == s) for s in STATUSES}

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [p for p in self.pairs if p["status"] == "failed"]

    @property
    def exit_status(self) -> int:
        if self.interrupted:
            return 130
        return 1 if self.failed or self.error else 0

    def as_dict(self) -> dict[str, Any]:
        from .. import __version__

        data: dict[str, Any] = jsonable(
            {
                "stereodepth": __version__,
                "runner": self.runner,
                "started": self.started,
                "elapsed_s": self.elapsed_s,
                "interrupted": self.interrupted,
                "error": self.error,
                "force": self.force,
                "counts": self.counts,
                "exit_status": self.exit_status,
                "notes": self.notes,
                "method": self.method,
                "matcher_options": self.matcher_options,
                "rectification": self.rectification,
                "pairs": self.pairs,
            }
        )
        return data
