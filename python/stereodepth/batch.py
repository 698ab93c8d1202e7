"""The ``stereodepth batch`` command: disparity, depth and point clouds for many stereo pairs,
on this machine or on a Dask cluster.

Input
    INPUT is a folder or a CSV file. In a folder, the first layout that matches is used:

    - sub-folders of left and right images with the same file names: ``image_2``/``image_3``
      (KITTI colour), ``image_0``/``image_1`` (KITTI grey), ``left``/``right``; KITTI
      calibration is read from ``calib/<frame>.txt`` (2012) or ``calib_cam_to_cam/<frame>.txt``
      (2015), the frame being the file name without its ``_10``/``_11`` suffix;
    - scene folders (INPUT itself and its sub-folders) holding a pair named by tokens:
      ``im0``/``im1`` (Middlebury, with its ``calib.txt``), ``left``/``right`` (any case), or
      the tokens of ``--pair-names``; the right image's name is the left's with the token
      replaced. A folder of ``0001_left.png``, ``0001_right.png`` ... works the same way.

    A CSV file lists ``left,right[,stem]`` per line (a first line ``left,right...`` is a
    header; blank lines and lines starting with ``#`` are skipped); relative paths are relative
    to the CSV file.

Calibration
    ``--focal-px`` and ``--baseline-mm`` (with ``--doffs-px``, ``--cx-px``, ``--cy-px``) apply
    to every pair; else ``--calib FILE`` (a Middlebury ``calib.txt`` or a KITTI calibration
    file) does; else each pair's own file (``calib.txt`` in its folder, or KITTI's). The number
    of disparities comes from ``--num-disparities``, else from ``ndisp`` in the Middlebury
    calibration; it is required otherwise.

Output, per pair with stem S, in OUTDIR
    ``S.disparity.EXT`` and ``S.depth.EXT`` (EXT by ``--format``: ``npy`` float32 disparity in
    pixels and depth in metres, NaN where invalid; ``png`` for ``png16``: disparity x 256 as
    KITTI, depth in millimetres, 0 where invalid; ``pfm`` float32, NaN where invalid),
    ``S.ply`` with ``--ply`` (binary, coloured by the left image, metres), and ``S.json`` last:
    the pair's record (inputs, calibration, options, outputs, density, time). At the end,
    ``report.json`` (or ``--report``) lists every pair's status, time and density.

    Every file is written to a temporary file and renamed, so a killed job leaves no
    half-written output. Running the same command again skips the pairs whose record matches
    (same inputs, options and calibration, outputs present) and redoes the rest; ``--force``
    redoes all. One job at a time may write to OUTDIR (a lock file guards it).

Running
    By default the pairs run in this process, three at a time on a thread pool, each using every
    core for the matcher. ``--workers N`` starts a local Dask cluster of N worker processes
    (loopback only) and ``--scheduler tcp://HOST:PORT`` uses an existing dask.distributed
    cluster, whose workers must see INPUT and OUTDIR at the same paths and have stereodepth
    installed. A worker that dies mid-pair is replaced and the pair is run again.

Exit status: 0 when every pair succeeded or was already done, 1 when any failed, 2 for a usage
error, 130 when interrupted (Ctrl-C: the pairs in flight finish, the rest are reported as
cancelled).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import json
import logging
import math
import os
import re
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import _validate as check
from .cli import key_value_option

__all__ = [
    "BatchOptions",
    "BatchReport",
    "Calibration",
    "Pair",
    "find_pairs",
    "process_pair",
    "register",
    "resolve_calibration",
    "run",
    "run_batch",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".pnm", ".bmp", ".tif", ".tiff", ".webp")
#: Left/right sub-folders, in the order they are tried, with their KITTI camera numbers.
FOLDER_PAIRS: tuple[tuple[str, str, tuple[int, int] | None], ...] = (
    ("image_2", "image_3", (2, 3)),
    ("image_0", "image_1", (0, 1)),
    ("left", "right", None),
)
#: Tokens that name the left and right image of a pair, in the order they are tried.
PAIR_NAMES: tuple[tuple[str, str], ...] = (
    ("im0", "im1"),
    ("left", "right"),
    ("Left", "Right"),
    ("LEFT", "RIGHT"),
)
FORMATS = {"npy": "npy", "png16": "png", "pfm": "pfm"}
STATUSES = ("ok", "skipped", "failed", "cancelled")
#: Pairs in flight in the embedded runner: decoding, writing and fsyncing some overlap the
#: matching of another (which uses every core). See bench/README.md for 1, 2 and 3.
EMBEDDED_IN_FLIGHT = 3
LOCK_NAME = ".stereodepth-batch.lock"


class UsageError(ValueError):
    """A mistake in the command or its input that no pair can get past (exit status 2)."""


# --- what a job is made of ----------------------------------------------------------------------
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

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Pair:
    """One stereo pair to process. ``calib_file`` is the calibration found beside it (with the
    KITTI cameras ``kitti_cams`` for a KITTI file); ``problem`` a reason it cannot run."""

    stem: str
    left: Path
    right: Path
    calib_file: Path | None = None
    kitti_cams: tuple[int, int] | None = None
    calibration: Calibration | None = None
    num_disparities: int | None = None
    problem: str | None = None


@dataclass(frozen=True)
class BatchOptions:
    """What every pair is computed with (besides its calibration)."""

    out_dir: Path
    format: str = "npy"
    ply: bool = False
    matcher: dict[str, Any] = field(default_factory=dict)  # block_match keyword arguments
    min_depth_m: float | None = None
    max_depth_m: float | None = None
    force: bool = False

    def output_paths(self, stem: str) -> dict[str, Path]:
        ext = FORMATS[self.format]
        out = {
            "disparity": self.out_dir / f"{stem}.disparity.{ext}",
            "depth": self.out_dir / f"{stem}.depth.{ext}",
        }
        if self.ply:
            out["ply"] = self.out_dir / f"{stem}.ply"
        return out

    def record_path(self, stem: str) -> Path:
        return self.out_dir / f"{stem}.json"


# --- finding the pairs ----------------------------------------------------------------------
def _is_image(p: Path) -> bool:
    return p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")


def _safe_stem(text: str) -> str:
    stem = re.sub(r"[\\/\x00-\x1f]+", "_", text).strip(" .")
    return stem or "pair"


def _token_split(stem: str, names: Sequence[tuple[str, str]]) -> tuple[str, str, str] | None:
    """(left token, right token, the stem without the token) for a left image's stem."""
    for left_tok, right_tok in names:
        i = stem.rfind(left_tok)
        if i >= 0:
            rest = stem[:i].rstrip("_-. ") + "_" + stem[i + len(left_tok) :].lstrip("_-. ")
            return left_tok, right_tok, rest.strip("_")
    return None


def _scene_pairs(d: Path, names: Sequence[tuple[str, str]], *, prefix: str | None) -> list[Pair]:
    pairs = []
    files = sorted(p for p in d.iterdir() if p.is_file() and _is_image(p))
    for f in files:
        split = _token_split(f.stem, names)
        if split is None:
            continue
        left_tok, right_tok, rest = split
        i = f.stem.rfind(left_tok)
        right_name = f.stem[:i] + right_tok + f.stem[i + len(left_tok) :] + f.suffix
        stem = (rest or d.name) if prefix is None else (f"{prefix}_{rest}" if rest else prefix)
        calib = d / "calib.txt"
        pairs.append(
            Pair(
                stem=_safe_stem(stem),
                left=f,
                right=d / right_name,
                calib_file=calib if calib.is_file() else None,
            )
        )
    return pairs


def _kitti_calib_for(root: Path, stem: str) -> Path | None:
    frame = re.sub(r"_\d\d$", "", stem)
    for sub in ("calib", "calib_cam_to_cam"):
        p = root / sub / f"{frame}.txt"
        if p.is_file():
            return p
    return None


def _folder_pairs(root: Path) -> list[Pair] | None:
    for left_dir, right_dir, cams in FOLDER_PAIRS:
        ld, rd = root / left_dir, root / right_dir
        if not (ld.is_dir() and rd.is_dir()):
            continue
        pairs = []
        shared_calib = root / "calib.txt"
        for f in sorted(p for p in ld.iterdir() if p.is_file() and _is_image(p)):
            calib = _kitti_calib_for(root, f.stem) if cams else None
            kitti = cams if calib is not None else None
            if calib is None and shared_calib.is_file():
                calib = shared_calib
            pairs.append(
                Pair(
                    stem=_safe_stem(f.stem),
                    left=f,
                    right=rd / f.name,
                    calib_file=calib,
                    kitti_cams=kitti,
                )
            )
        return pairs
    return None


def _csv_pairs(path: Path, names: Sequence[tuple[str, str]]) -> list[Pair]:
    import csv

    pairs = []
    first = True
    with path.open(newline="", encoding="utf-8") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            cells = [c.strip() for c in row]
            if not cells or not any(cells) or cells[0].startswith("#"):
                continue
            if first and cells[0].lower() == "left":
                first = False
                continue  # header
            first = False
            if len(cells) not in (2, 3) or not cells[0] or not cells[1]:
                raise UsageError(
                    f"{path}:{lineno}: expected left,right[,stem], got {','.join(row)!r}"
                )
            left = (path.parent / cells[0]) if not Path(cells[0]).is_absolute() else Path(cells[0])
            right = (path.parent / cells[1]) if not Path(cells[1]).is_absolute() else Path(cells[1])
            if len(cells) == 3 and cells[2]:
                stem = cells[2]
            else:
                split = _token_split(left.stem, names)
                stem = (split[2] if split else left.stem) or left.parent.name
            calib = left.parent / "calib.txt"
            pairs.append(
                Pair(
                    stem=_safe_stem(stem),
                    left=left,
                    right=right,
                    calib_file=calib if calib.is_file() else None,
                )
            )
    return pairs


def find_pairs(
    input_path: str | os.PathLike[str],
    *,
    pair_names: Sequence[tuple[str, str]] | None = None,
) -> list[Pair]:
    """The stereo pairs of a folder or a CSV list (see the module's documentation), in order.

    Pairs whose right image is missing are returned too (they fail when processed, and the
    report names them). Raises UsageError when nothing is found or two pairs would write the
    same outputs."""
    root = Path(input_path)
    names = list(pair_names) if pair_names else list(PAIR_NAMES)
    if not root.exists():
        raise UsageError(f"INPUT not found: {root}")
    if root.is_file():
        if root.suffix.lower() != ".csv":
            raise UsageError(f"INPUT must be a folder or a .csv list of pairs, got {root}")
        pairs = _csv_pairs(root, names)
    else:
        found = _folder_pairs(root)
        if found is None:
            found = _scene_pairs(root, names, prefix=None)
            for sub in sorted(p for p in root.iterdir() if p.is_dir()):
                if not sub.name.startswith("."):
                    found += _scene_pairs(sub, names, prefix=sub.name)
        pairs = found
    if not pairs:
        tokens = ", ".join(f"{a}/{b}" for a, b in names)
        raise UsageError(
            f"no stereo pairs found in {root}: expected image_2/image_3 (or image_0/image_1, "
            f"left/right) folders, scene folders with pairs named {tokens}, or a CSV list"
        )
    seen: dict[str, Pair] = {}
    for p in pairs:
        if p.stem in seen:
            raise UsageError(
                f"two pairs would write the same outputs {p.stem!r}: {seen[p.stem].left} and "
                f"{p.left} (give output stems in a CSV list)"
            )
        seen[p.stem] = p
    return pairs


# --- calibration ----------------------------------------------------------------------------
def read_kitti_calib(path: str | os.PathLike[str], cams: tuple[int, int] = (2, 3)) -> Calibration:
    """The rig of two rectified KITTI cameras from a calibration file (``P2: ...`` as in KITTI
    2012's ``calib/*.txt``, or ``P_rect_02: ...`` as in 2015's ``calib_cam_to_cam``)."""
    p = Path(path)
    mats: dict[int, np.ndarray] = {}
    for line in p.read_text().splitlines():
        m = re.match(r"\s*P(?:_rect_)?0?(\d)\s*:\s*(.*)$", line)
        if not m:
            continue
        try:
            vals = [float(v) for v in m.group(2).split()]
        except ValueError as exc:
            raise ValueError(f"{p}: P{m.group(1)} must be 12 numbers, got {m.group(2)!r}") from exc
        if len(vals) != 12:
            raise ValueError(f"{p}: P{m.group(1)} must be 12 numbers, got {len(vals)}")
        mats[int(m.group(1))] = np.array(vals).reshape(3, 4)
    lc, rc = cams
    for c in (lc, rc):
        if c not in mats:
            raise ValueError(f"{p}: missing P{c} (or P_rect_0{c}) in the KITTI calibration")
    pl, pr = mats[lc], mats[rc]
    f = float(pl[0, 0])
    if not f > 0:
        raise ValueError(f"{p}: P{lc} focal length must be > 0, got {f}")
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
    from .calib import read_middlebury_calib

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


def resolve_calibration(
    pairs: Sequence[Pair],
    *,
    given: Calibration | None = None,
    calib_file: Path | None = None,
    num_disparities: int | None = None,
) -> list[Pair]:
    """Each pair with its calibration and number of disparities, or the problem that stops it.

    ``given`` (from the command line) wins over ``calib_file`` which wins over each pair's own
    file. Raises UsageError when no pair has a calibration or a number of disparities, so a
    forgotten option is one clear error rather than a failure per pair."""
    from dataclasses import replace

    shared = given
    if shared is None and calib_file is not None:
        try:
            shared = read_calibration(calib_file, pairs[0].kitti_cams if pairs else None)
        except (OSError, ValueError) as exc:
            raise UsageError(f"--calib: {exc}") from exc
    out = []
    cache: dict[tuple[Path, tuple[int, int] | None], Calibration | str] = {}
    for p in pairs:
        calib: Calibration | None = shared
        problem = p.problem
        if calib is None and p.calib_file is not None:
            key = (p.calib_file, p.kitti_cams)
            if key not in cache:
                try:
                    cache[key] = read_calibration(p.calib_file, p.kitti_cams)
                except (OSError, ValueError) as exc:
                    cache[key] = f"bad calibration: {exc}"
            found = cache[key]
            if isinstance(found, str):
                problem = problem or found
            else:
                calib = found
        if calib is None:
            problem = problem or (
                "no calibration: give --focal-px and --baseline-mm, or --calib FILE, or put a "
                "calib.txt beside the images"
            )
        nd = num_disparities
        if nd is None and calib is not None:
            nd = calib.num_disparities
        if nd is None and calib is not None:
            problem = problem or "no --num-disparities and no ndisp in the calibration"
        out.append(replace(p, calibration=calib, num_disparities=nd, problem=problem))
    if (
        out
        and all(p.calibration is None for p in out)
        and all(p.problem and p.problem.startswith("no calibration") for p in out)
    ):
        raise UsageError(
            "no calibration for any pair: give --focal-px and --baseline-mm, or --calib FILE "
            "(Middlebury calib.txt or KITTI calib)"
        )
    if (
        out
        and num_disparities is None
        and all(p.num_disparities is None for p in out)
        and any(p.calibration is not None for p in out)
    ):
        raise UsageError(
            "--num-disparities is required (no Middlebury calib.txt with ndisp was found)"
        )
    return out


# --- one pair ---------------------------------------------------------------------------------
def _file_stamp(p: Path) -> dict[str, Any]:
    st = p.stat()
    return {"path": str(p), "bytes": st.st_size, "mtime_ns": st.st_mtime_ns}


def _settings(pair: Pair, options: BatchOptions) -> dict[str, Any]:
    """Everything the outputs of a pair depend on (compared when resuming)."""
    from . import __version__

    if pair.calibration is None:
        raise ValueError(f"pair {pair.stem} has no calibration")
    return {
        "stereodepth": __version__,
        "format": options.format,
        "ply": options.ply,
        "min_depth_m": options.min_depth_m,
        "max_depth_m": options.max_depth_m,
        "num_disparities": pair.num_disparities,
        "matcher": {k: v for k, v in sorted(options.matcher.items()) if k != "threads"},
        "calibration": {k: v for k, v in pair.calibration.as_dict().items() if k != "source"},
    }


def completed_record(pair: Pair, options: BatchOptions) -> dict[str, Any] | None:
    """The record of an earlier run when it is complete and made with the same inputs and
    settings, else None."""
    if pair.problem or pair.calibration is None:
        return None
    path = options.record_path(pair.stem)
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        if record.get("status") != "ok" or record.get("settings") != _jsonable(
            _settings(pair, options)
        ):
            return None
        inputs = record["inputs"]
        if inputs != {"left": _file_stamp(pair.left), "right": _file_stamp(pair.right)}:
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


def _jsonable(value: Any) -> Any:
    """JSON-safe: non-finite floats as None, tuples as lists, paths as strings."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.generic):
        return value.item()
    return value


def _to_grey(rgb: np.ndarray) -> np.ndarray:
    """OpenCV's COLOR_RGB2GRAY, as the matcher converts RGB internally."""
    r, g, b = (rgb[..., i].astype(np.uint32) for i in range(3))
    return ((4899 * r + 9617 * g + 1868 * b + 8192) >> 14).astype(np.uint8)


def _load_pair(pair: Pair) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """(left, right, colours, stamps): the pair made comparable for the matcher, the left image
    as read for the point cloud's colours, and the files' size and time, taken before reading
    them (so that a file changed meanwhile is redone next time)."""
    from .io import read_image

    if not pair.left.is_file():
        raise FileNotFoundError(f"missing left image {pair.left}")
    if not pair.right.is_file():
        raise FileNotFoundError(f"missing right image {pair.right}")
    stamps = {"left": _file_stamp(pair.left), "right": _file_stamp(pair.right)}
    left, right = read_image(pair.left), read_image(pair.right)
    if left.shape[:2] != right.shape[:2]:
        raise ValueError(
            f"left and right differ in size: {left.shape[1]}x{left.shape[0]} and "
            f"{right.shape[1]}x{right.shape[0]} px"
        )
    colours = left
    if left.ndim != right.ndim:  # one RGB, one grey: match in grey
        left = _to_grey(left) if left.ndim == 3 else left
        right = _to_grey(right) if right.ndim == 3 else right
    if left.dtype != right.dtype:
        raise ValueError(f"left and right differ in bit depth: {left.dtype} and {right.dtype}")
    return left, right, colours, stamps


def _write_map(path: Path, kind: str, array: np.ndarray, fmt: str) -> None:
    from . import io

    if fmt == "npy":
        io.write_npy(path, array)
    elif fmt == "pfm":
        io.write_pfm(path, array)
    elif kind == "disparity":
        io.write_disparity_png16(path, array)
    else:
        io.write_png16(path, array)


def _record(pair: Pair, status: str, error: str | None = None) -> dict[str, Any]:
    """The fields every record of a pair starts with; the rest are filled in as known."""
    return {
        "stem": pair.stem,
        "left": str(pair.left),
        "right": str(pair.right),
        "status": status,
        "error": error,
        "time_s": None,
        "density": None,
    }


def process_pair(pair: Pair, options: BatchOptions, threads: int | None = None) -> dict[str, Any]:
    """Computes and writes one pair's outputs; never raises for a bad pair.

    Returns the pair's record: ``stem``, ``left``, ``right``, ``status`` (``ok`` or
    ``failed``), ``error``, ``time_s``, ``density`` (the fraction of pixels with a
    disparity), ``width``, ``height``, ``outputs`` and ``settings``. The record is also
    written, last, as ``<stem>.json`` when the pair succeeds."""
    from . import __version__, disparity_to_depth
    from .io import atomic_write
    from .pointcloud import reproject, write_ply

    t0 = time.perf_counter()
    record = _record(pair, "failed")
    try:
        if pair.problem:
            raise ValueError(pair.problem)
        calib = pair.calibration
        if calib is None or pair.num_disparities is None:
            raise ValueError("no calibration or number of disparities for this pair")
        threads = _task_threads() if threads is None else threads
        left, right, colours, stamps = _load_pair(pair)
        from .matching import thread_matcher

        matcher = thread_matcher(
            num_disparities=pair.num_disparities, **{**options.matcher, "threads": threads}
        )
        disparity = matcher.compute(left, right)
        if not isinstance(disparity, np.ndarray):  # pragma: no cover - no confidence asked
            raise TypeError("block_match returned more than the disparity")
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
        paths = options.output_paths(pair.stem)
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
            n = write_ply(
                paths["ply"], points, colours, comment=f"stereodepth {__version__}: {stem}, metres"
            )
            outputs["ply_points"] = n
        density = float(np.count_nonzero(np.isfinite(disparity))) / max(disparity.size, 1)
        record.update(
            status="ok",
            width=int(disparity.shape[1]),
            height=int(disparity.shape[0]),
            density=density,
            inputs=stamps,
            outputs={k: {"path": str(p), "bytes": p.stat().st_size} for k, p in paths.items()},
            settings=_settings(pair, options),
        )
        if "ply_points" in outputs:
            record["outputs"]["ply"]["points"] = outputs["ply_points"]
        record["time_s"] = time.perf_counter() - t0
        with atomic_write(options.record_path(pair.stem), text=True) as fh:
            json.dump(_jsonable(record), fh, indent=2, allow_nan=False)
            fh.write("\n")
    except Exception as exc:  # a bad pair is reported, never fatal
        known = (OSError, ValueError, TypeError, MemoryError)
        text = str(exc) if isinstance(exc, known) and str(exc) else f"{type(exc).__name__}: {exc}"
        record.update(status="failed", error=text)
        record["time_s"] = time.perf_counter() - t0
    result: dict[str, Any] = _jsonable(record)
    return result


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


# --- the job ----------------------------------------------------------------------------------
@dataclass
class BatchReport:
    """What a job did: one record per pair, in input order, and the totals."""

    pairs: list[dict[str, Any]]
    runner: str
    elapsed_s: float
    interrupted: bool = False
    started: str = ""
    removed_temp_files: int = 0

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
        return 1 if self.failed else 0

    def as_dict(self) -> dict[str, Any]:
        from . import __version__

        data: dict[str, Any] = _jsonable(
            {
                "stereodepth": __version__,
                "runner": self.runner,
                "started": self.started,
                "elapsed_s": self.elapsed_s,
                "interrupted": self.interrupted,
                "counts": self.counts,
                "exit_status": self.exit_status,
                "pairs": self.pairs,
            }
        )
        return data


@contextlib.contextmanager
def _exclusive(out_dir: Path) -> Iterator[None]:
    """Holds a lock on OUTDIR so that two jobs never write there at once."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    fd = os.open(out_dir / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UsageError(f"another stereodepth batch job is writing to {out_dir}") from None
        yield
    finally:
        os.close(fd)


class _Progress:
    """A tqdm bar on stderr (when ``enabled``), or nothing."""

    def __init__(self, total: int, enabled: bool) -> None:
        self._bar: Any = None
        self.failed = 0
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(
                total=total,
                unit="pair",
                file=sys.stderr,
                dynamic_ncols=True,
                desc="stereodepth batch",
            )

    def update(self, record: dict[str, Any]) -> None:
        if record["status"] == "failed":
            self.failed += 1
        if self._bar is not None:
            if self.failed:
                self._bar.set_postfix(failed=self.failed, refresh=False)
            self._bar.update(1)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def _run_embedded(
    todo: list[tuple[int, Pair]],
    options: BatchOptions,
    done: Callable[[int, dict[str, Any]], None],
    threads: int | None,
) -> None:
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    pool = ThreadPoolExecutor(max_workers=EMBEDDED_IN_FLIGHT, thread_name_prefix="stereodepth")
    futures = {pool.submit(process_pair, p, options, threads): i for i, p in todo}
    pending = set(futures)
    try:
        while pending:
            finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
            for f in finished:
                done(futures[f], f.result())
    except KeyboardInterrupt:
        # Let the pairs in flight finish (their files are then complete); drop the rest.
        for f in pending:
            f.cancel()
        pool.shutdown(wait=True)
        for f in pending:
            if f.done() and not f.cancelled():
                done(futures[f], f.result())
        raise
    pool.shutdown(wait=True)


def _run_dask(
    todo: list[tuple[int, Pair]],
    options: BatchOptions,
    done: Callable[[int, dict[str, Any]], None],
    threads: int | None,
    client: Any,
    stop: threading.Event,
) -> None:
    """Runs the pairs on the client's cluster until all are done or ``stop`` is set (Ctrl-C,
    see :func:`_sigint_as_flag`): then the tasks not started are cancelled, the results that
    already arrived are kept, and KeyboardInterrupt is raised here, outside Dask's calls."""
    import queue

    run_id = uuid.uuid4().hex[:8]
    futures = {}
    for i, p in todo:
        f = client.submit(
            process_pair, p, options, threads, key=f"stereodepth-{run_id}-{i}", pure=False
        )
        futures[f] = i
    pairs = dict(todo)
    arrived: queue.SimpleQueue[Any] = queue.SimpleQueue()
    for f in futures:
        f.add_done_callback(arrived.put)  # called from Dask's thread when the task ends
    pending = set(futures)
    while pending:
        if stop.is_set():
            client.cancel([f for f in pending if not f.done()])
            for f in pending:
                if f.done() and f.status == "finished":
                    done(futures[f], f.result())
            raise KeyboardInterrupt
        try:
            f = arrived.get(timeout=0.2)
        except queue.Empty:
            continue
        pending.discard(f)  # Dask calls a future's callback once
        i = futures[f]
        try:
            record = f.result()
        except Exception as exc:  # the task itself never raises: a worker kept dying
            record = _record(pairs[i], "failed", f"{type(exc).__name__}: {exc}")
        done(i, record)


def run_batch(
    pairs: Sequence[Pair],
    options: BatchOptions,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    threads: int | None = None,
    progress: bool = False,
    on_result: Callable[[dict[str, Any]], None] | None = None,
) -> BatchReport:
    """Runs a job: every pair not already done, on this machine (default), on a local Dask
    cluster of ``workers`` processes, or on the Dask cluster at ``scheduler``.

    Pairs need their calibration (:func:`resolve_calibration`). ``threads`` is the matcher's
    thread count per pair; by default every core, the cores / ``workers`` on a local cluster,
    and on a ``scheduler`` cluster a worker's cores / its number of threads.
    ``on_result`` is called in this thread with each record as it arrives. Ctrl-C
    (KeyboardInterrupt) stops the job: the pairs in flight finish, the rest are ``cancelled``,
    and the report says ``interrupted``. Writes ``<stem>.*`` files into ``options.out_dir``;
    the caller writes the report."""
    from .io import remove_temp_files

    if scheduler is not None and workers is not None:
        raise UsageError("give --scheduler or --workers, not both")
    if workers is not None and workers < 1:
        raise UsageError(f"--workers must be an integer >= 1, got {workers}")
    if threads is not None and threads < 0:
        raise UsageError(f"--threads must be an integer >= 0 (0: every core), got {threads}")
    out_dir = options.out_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    started = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    records: list[dict[str, Any] | None] = [None] * len(pairs)
    removed = 0
    interrupted = False
    runner = "embedded"
    with _exclusive(out_dir):
        bar = _Progress(len(pairs), progress)

        def done(i: int, record: dict[str, Any]) -> None:
            records[i] = record
            bar.update(record)
            if on_result is not None:
                on_result(record)

        try:
            removed += len(remove_temp_files(out_dir))
            todo: list[tuple[int, Pair]] = []
            for i, p in enumerate(pairs):
                earlier = None if options.force else completed_record(p, options)
                if earlier is None:
                    todo.append((i, p))
                    continue
                keep = ("time_s", "density", "width", "height", "outputs")
                done(i, {**_record(p, "skipped"), **{k: earlier.get(k) for k in keep}})
            if scheduler is None and workers is None:
                if todo:
                    _run_embedded(todo, options, done, threads)
            else:
                with (
                    _sigint_as_flag() as stop,
                    _dask_client(scheduler, workers, threads) as (client, runner, task_threads),
                ):
                    if todo:
                        _run_dask(todo, options, done, task_threads, client, stop)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            bar.close()
            removed += len(remove_temp_files(out_dir))
    final = []
    for i, p in enumerate(pairs):
        rec = records[i]
        if rec is None:
            # Interrupted: a pair whose result did not reach us may have finished anyway.
            earlier = completed_record(p, options)
            rec = _record(p, "cancelled")
            if earlier is not None:
                rec.update(
                    {
                        k: earlier.get(k)
                        for k in ("status", "time_s", "density", "width", "height", "outputs")
                    }
                )
        final.append(rec)
    return BatchReport(
        pairs=final,
        runner=runner,
        elapsed_s=time.perf_counter() - t0,
        interrupted=interrupted,
        started=started,
        removed_temp_files=removed,
    )


@contextlib.contextmanager
def _sigint_handled_by(handler: Any) -> Iterator[None]:
    """SIGINT goes to ``handler`` (a function or ``signal.SIG_IGN``) for the block's duration,
    then the previous handler comes back. A no-op outside the main thread, where signal
    handlers cannot be set."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _sigint_as_flag() -> Iterator[threading.Event]:
    """For the block's duration, Ctrl-C (SIGINT) sets the returned event instead of raising
    KeyboardInterrupt wherever the main thread happens to be.

    dask.distributed's blocking calls are not safe to interrupt: a KeyboardInterrupt that lands
    inside one can leave its event loop thread printing a traceback. The Dask runner checks the
    event between calls and stops the job itself, and the cluster then shuts down in order; a
    second Ctrl-C raises KeyboardInterrupt as usual. Only Python's default handler is replaced:
    an application's own handler, an ignored SIGINT and threads other than the main one are
    left alone (the event is then never set)."""
    stop = threading.Event()

    def handler(signum: int, frame: Any) -> None:
        if stop.is_set():  # a second Ctrl-C: the user will not wait for the orderly stop
            raise KeyboardInterrupt
        stop.set()

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield stop
        return
    with _sigint_handled_by(handler):
        yield stop


@contextlib.contextmanager
def _dask_client(
    scheduler: str | None, workers: int | None, threads: int | None
) -> Iterator[tuple[Any, str, int | None]]:
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise UsageError(
            'running on Dask needs dask.distributed: pip install "stereodepth[batch]"'
        ) from exc
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")  # type: ignore[no-untyped-call]
        except OSError as exc:
            raise UsageError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from exc
        with client:
            yield client, f"dask {scheduler}", threads
        return
    assert workers is not None
    task_threads = threads if threads is not None else max(1, check.available_cores() // workers)
    # The scheduler's HTTP server binds a free loopback port: with dashboard_address=None it
    # would still try port 8787 and warn (or fail) when that is taken.
    # Ctrl-C in a terminal reaches every process of the group: the worker processes start with
    # SIGINT ignored (their children inherit it), so that this process alone stops the job
    # and shuts the cluster down, rather than each worker dying with a traceback.
    with _sigint_handled_by(signal.SIG_IGN):
        cluster = LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            silence_logs=logging.ERROR,
        )
    with cluster, Client(cluster) as client:  # type: ignore[no-untyped-call]
        yield client, f"local dask cluster of {workers} worker processes", task_threads


# --- the command --------------------------------------------------------------------------------
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
    from .matching import BlockMatchOptions

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
    from .io import atomic_write

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
