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

from ..calib import Calibration, read_calibration, read_kitti_calib
from .calibration import resolve_calibration
from .command import print_summary, register, run
from .compute import process_pair
from .discovery import FOLDER_PAIRS, IMAGE_SUFFIXES, PAIR_NAMES, find_pairs
from .job import FORMATS, STATUSES, BatchOptions, Pair, UsageError
from .records import BatchReport, completed_record
from .runners import EMBEDDED_IN_FLIGHT, LOCK_NAME, run_batch

__all__ = [
    "EMBEDDED_IN_FLIGHT",
    "FOLDER_PAIRS",
    "FORMATS",
    "IMAGE_SUFFIXES",
    "LOCK_NAME",
    "PAIR_NAMES",
    "STATUSES",
    "BatchOptions",
    "BatchReport",
    "Calibration",
    "Pair",
    "UsageError",
    "completed_record",
    "find_pairs",
    "print_summary",
    "process_pair",
    "read_calibration",
    "read_kitti_calib",
    "register",
    "resolve_calibration",
    "run",
    "run_batch",
]
