"""What a batch job is made of: the pairs, the options every pair is computed with, and the
error that stops a job before it starts."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..calib import Calibration

if TYPE_CHECKING:
    from .calibration import BatchRectifier

FORMATS = {"npy": "npy", "png16": "png", "pfm": "pfm"}
STATUSES = ("ok", "skipped", "failed", "cancelled")
#: A pair's record is ``<stem>.record.json``: no other file of a job ends so (the report is
#: ``report.json`` by default), so a pair named ``report`` cannot overwrite the report.
RECORD_SUFFIX = ".record.json"


def read_record(path: Path) -> dict[str, Any] | None:
    """A pair's record as a dict, or None for a file that is missing, unreadable, not JSON
    (nested too deeply included) or not a JSON object: records may be edited by hand or
    left by another program, and such a file is never a record of ours."""
    import json

    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    return record if isinstance(record, dict) else None


class UsageError(ValueError):
    """A mistake in the command or its input that no pair can get past (exit status 2)."""


@dataclass(frozen=True)
class Pair:
    """One stereo pair to process. ``calib_file`` is the calibration found beside it;
    ``kitti_cams`` the KITTI cameras of its folders (``image_2``/``image_3``: (2, 3),
    ``image_0``/``image_1``: (0, 1)), those read from any KITTI file that calibrates it (its
    own, a shared ``calib.txt`` or ``--calib``); ``problem`` a reason it cannot run;
    ``calib_file_unused`` says that a calibration from the command line replaced
    ``calib_file``."""

    stem: str
    left: Path
    right: Path
    calib_file: Path | None = None
    kitti_cams: tuple[int, int] | None = None
    calibration: Calibration | None = None
    num_disparities: int | None = None
    problem: str | None = None
    calib_file_unused: bool = False


@dataclass(frozen=True)
class BatchOptions:
    """What every pair is computed with (besides its calibration).

    ``method`` names the matcher, ``"bm"`` (:func:`stereodepth.block_match`) or ``"sgm"``
    (:func:`stereodepth.semi_global_match`), and ``matcher`` holds its keyword arguments
    (``num_disparities`` and ``threads`` come from the pair and the runner). ``rectification``
    rectifies every pair before matching (a raw ``--calib`` file); ``write_rectified`` also
    writes the rectified pair."""

    out_dir: Path
    format: str = "npy"
    ply: bool = False
    preview: bool = False  # colour PNGs of the disparity and the depth, with colour bars
    matcher: dict[str, Any] = field(default_factory=dict)  # the method's keyword arguments
    min_depth_m: float | None = None
    max_depth_m: float | None = None
    force: bool = False
    method: str = "bm"
    rectification: BatchRectifier | None = None
    write_rectified: bool = False

    def __post_init__(self) -> None:
        """The fields every pair is named and written by, checked once: a str OUTDIR was an
        AttributeError ('str' object has no attribute 'parents'), and an unknown format or
        method failed every pair (``KeyError: 'tif'``), writing a failed record for each."""
        import os

        from .._methods import check_method

        if isinstance(self.out_dir, str) or (
            isinstance(self.out_dir, os.PathLike) and not isinstance(self.out_dir, Path)
        ):
            object.__setattr__(self, "out_dir", Path(self.out_dir))
        if not isinstance(self.out_dir, Path):
            raise TypeError(
                f"out_dir must be a path (str or os.PathLike), got "
                f"{type(self.out_dir).__name__} {self.out_dir!r}"
            )
        if not isinstance(self.format, str) or self.format not in FORMATS:
            raise ValueError(
                f"format must be one of {', '.join(map(repr, FORMATS))}, got {self.format!r}"
            )
        check_method(self.method, "method")

    def output_paths(self, stem: str) -> dict[str, Path]:
        ext = FORMATS[self.format]
        out = {
            "disparity": self.out_dir / f"{stem}.disparity.{ext}",
            "depth": self.out_dir / f"{stem}.depth.{ext}",
        }
        if self.ply:
            out["ply"] = self.out_dir / f"{stem}.ply"
        if self.preview:
            for kind in ("disparity", "depth"):
                out[f"{kind}_preview"] = self.out_dir / f"{stem}.{kind}.preview.png"
        if self.write_rectified:
            for side in ("left", "right"):
                out[f"{side}_rectified"] = self.out_dir / f"{stem}.{side}-rectified.png"
        return out

    def record_path(self, stem: str) -> Path:
        return self.out_dir / f"{stem}{RECORD_SUFFIX}"

    def owned_names(self, stem: str) -> set[str]:
        """The names of every file a pair may write into OUTDIR (:func:`owned_names`)."""
        return owned_names(stem)


def owned_names(stem: str) -> set[str]:
    """The names of every file the pair ``stem`` may write into OUTDIR, in any format, with
    or without ``--ply``, ``--preview`` or ``--write-rectified``: the only files batch ever
    removes (when they are stale)."""
    names = {f"{stem}.{kind}.{ext}" for kind in ("disparity", "depth") for ext in FORMATS.values()}
    previews = {f"{stem}.{kind}.preview.png" for kind in ("disparity", "depth")}
    rectified = {f"{stem}.{side}-rectified.png" for side in ("left", "right")}
    return names | previews | rectified | {f"{stem}.ply", f"{stem}{RECORD_SUFFIX}"}
