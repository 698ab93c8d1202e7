"""The ``stereodepth batch`` command: disparity, depth and point clouds for many stereo pairs,
on this machine or on a Dask cluster.

Modules: :mod:`~.discovery` (finding pairs), :mod:`~.calibration` (which calibration each pair
uses), :mod:`~.records` (per-pair records, resuming, the report), :mod:`~.compute` (one pair),
:mod:`~.runners` (embedded and Dask), :mod:`~.command` (the command line). Calibration files
are read by :mod:`stereodepth.calib`.

Input
    INPUT is a folder or a CSV file. A folder is searched down to three levels of sub-folders
    below it (``SEARCH_DEPTH``; hidden folders and OUTDIR are left out). In each folder:

    - a folder holding sub-folders of left and right images with the same file names,
      ``image_2``/``image_3`` (KITTI colour), ``image_0``/``image_1`` (KITTI grey) or
      ``left``/``right``, is one set of pairs (its other sub-folders are not searched, and
      those holding images are listed; of two such layouts side by side, the first in this
      order is used, the other listed); KITTI
      calibration is read from ``calib/<frame>.txt`` (2012) or
      ``calib_cam_to_cam/<frame>.txt`` (2015), the frame being the file name without its
      ``_10``/``_11`` suffix;
    - any other folder gives the pairs named by tokens in it: ``im0``/``im1`` (Middlebury, with
      its ``calib.txt``), ``left``/``right`` (any case), or the tokens of ``--pair-names``
      (two different tokens, neither part of the other); the right image's name is the left's
      with the token replaced. A folder of ``0001_left.png``, ``0001_right.png`` ... works the
      same way.

    A pair's stem (its output names) is its folder's path below INPUT joined by ``_``, with
    the rest of the left image's name. Folders that hold images but give no pair, right
    sub-folders' images with no left image of their name, and folders deeper than the search,
    are listed with the reason (on stderr and in the report), never dropped silently. With
    OUTDIR = INPUT or a folder of left images (KITTI's ``image_2``), the images of a pair's
    outputs (``S.left-rectified.png``, ``S.depth.png``...) are not pairs, even those of a job
    killed before the pair's record listed them (they are listed too).

    A CSV file lists ``left,right[,stem]`` per line, UTF-8, LF or CR LF line ends; cells are
    stripped of spaces (a quoted cell may follow spaces: ``a.png, "b 1.png"``); an optional
    header ``left,right[,stem]`` comes first; blank lines and lines whose first cell starts
    with ``#`` are skipped; relative paths are relative to the CSV file. Any other line is an
    error naming the file and line.

Images
    Images are read by Pillow: colour images come as RGB (``--channel-order bgr`` for files
    whose channels were stored swapped: the matcher reads them so, and the point cloud is
    coloured in RGB), grey ones as 8 or 16 bit. Left and right must both
    be colour or both grey, of the same size and bit depth, as :func:`stereodepth.block_match`
    requires: a mixed pair fails with a message saying which is which.

Matcher
    ``--method bm`` (:func:`stereodepth.block_match`, the default) or ``--method sgm``
    (:func:`stereodepth.semi_global_match`). ``--min-disparity`` and ``--block-size`` apply to
    both, ``--cost`` to bm only; ``--option KEY=VALUE`` passes any other keyword of the chosen
    matcher. Every option is checked against the chosen method before the first pair
    (:mod:`stereodepth._methods` names each method's matcher and options): an option of the
    other method is an error naming the flag, the method and its options. Records and the
    report hold ``method`` and ``matcher_options``.

Calibration
    A pair's rig comes whole from the first of: ``--focal-px`` and ``--baseline-mm`` (with
    ``--doffs-px``, ``--cx-px``, ``--cy-px``); ``--calib FILE`` (a Middlebury ``calib.txt`` or
    a KITTI calibration file, or a raw calibration); the pair's own file (``calib.txt`` in its
    folder, or KITTI's).
    The number of disparities is ``--num-disparities``, else ``ndisp`` of the file the rig
    came from (KITTI files have none). Each record names the source used
    (``calibration_source``) and the pair's own file when an option replaced it
    (``calibration_not_used``); the command says so in a note.

Raw pairs
    A ``--calib`` file that is not a Middlebury or KITTI calibration (OpenCV FileStorage
    YAML/XML/JSON, Kalibr camchain, ROS camera_info with ``--calib-right``; ``--translation-unit``,
    ``--distortion-model``)
    describes raw pairs: every pair is rectified before matching, by the rule of ``stereodepth
    match`` (:mod:`stereodepth._calib_rule`, shared; ``--alpha`` too). The rectifier is built once
    (:class:`~.calibration.BatchRectifier`; on Dask the calibration is shipped and each worker
    process builds the maps once) and the rig is the rectifier's: the disparity, depth,
    previews and point clouds are of the rectified left camera, in its frame (``x_rect = R1 @
    x_raw``), at the rectified size. ``--num-disparities`` is required (raw calibrations have
    no ndisp). Records say ``rectified`` and ``settings.rectification``; a pair whose size is
    not the calibration's fails alone; ``--write-rectified`` also writes
    ``S.left-rectified.png`` and ``S.right-rectified.png``; ``--no-rectify`` makes a raw
    calibration an error.

Output, per pair with stem S, in OUTDIR
    ``S.disparity.EXT`` and ``S.depth.EXT`` (EXT by ``--format``: ``npy`` float32 disparity in
    pixels and depth in metres, NaN where invalid; ``png`` for ``png16``: disparity x 256 as
    KITTI (0 to 255.996 px: a search range outside that is refused), depth in millimetres, 0
    where invalid, 1 for 1 mm and nearer, 65535 for 65.535 m and farther; ``pfm`` float32,
    disparity +inf where invalid as Middlebury's, depth NaN),
    ``S.ply`` with ``--ply`` (binary, coloured by the left image, metres), and
    ``S.record.json`` last: the pair's record (status, inputs, calibration, options, outputs,
    density, time), written for a failed pair too, and first, before the pair's first file,
    with status ``started`` and the files to come (a pair killed midway is then redone, and
    its files are known as the job's: a file at a pair's output path that no record lists is
    not replaced without ``--force``). At the end, ``report.json`` (or
    ``--report FILE``, whose folder must exist) lists every pair's status, time and density.
    No pair's file can be named like the report; a ``--report`` that names a file of a pair
    or an input is refused, and a file already at the report's path that is not a batch
    report is not replaced without ``--force``.

    Every file is written to a temporary file and renamed, so a killed job leaves no
    half-written output. Running the same command again skips the pairs whose record matches
    (same inputs, options and calibration, the image size it is for included, outputs
    present) and redoes the rest; ``--force``
    redoes all. An input is the file itself (its real path, size and time), however INPUT is
    spelled: a job resumes from another folder, or here after its Dask cluster went away. A
    job whose pair would replace a pair's outputs made from other images (a second job into
    the same OUTDIR, its stems the first's) is refused before any pair; ``--force`` replaces
    them. A pair that is redone loses the files of its earlier run that this run does not
    write again (another ``--format``, a ``.ply`` no longer asked for, everything when it now
    fails); its record lists them under ``removed``. A file without write permission (one the
    user made read-only to keep) is never replaced or removed. One job at a time may write to
    OUTDIR: a lock file, ``.stereodepth-batch.lock``, guards it and is removed when the job
    ends.

Running
    By default the pairs run in this process, three at a time on a thread pool, each using every
    core for the matcher. ``--workers N`` starts a local Dask cluster of N worker processes
    (loopback only; N at most the cores) and ``--scheduler tcp://HOST:PORT`` uses an existing
    dask.distributed cluster, whose workers must see INPUT and OUTDIR at the same paths and
    have stereodepth installed (relative paths are made absolute first: the workers run in
    folders of their own); an address where no scheduler answers within 12 s is refused. A
    worker that dies mid-pair is replaced and the pair is run again.

Errors
    Everything no pair could get past is checked before the first pair: the options (matcher
    options for the chosen method, depth range, pair names, runner, the scheduler's address),
    a raw calibration (read, and its rectifier built), the optional extras (Pillow; tqdm for the
    progress bar; dask.distributed for Dask), the output locations, the pairs and their
    calibration. Each is one line on stderr.

Exit status: 0 when every pair succeeded or was already done, 1 when any failed (or an
optional extra is missing, or the Dask cluster failed the job: its scheduler lost mid-job,
or workers without this version of stereodepth or Pillow, found before the first pair; the
pairs not done are reported as cancelled and keep their earlier outputs), 2 for a usage
error, 130 when interrupted (Ctrl-C: the pairs in flight finish, the rest are reported as
cancelled), 143 when terminated (SIGTERM, from ``timeout`` or ``kill``: the same as Ctrl-C).
The summary on stdout comes after every output and the report are written: one that cannot be
printed leaves the status as it was (its reader gone, a broken pipe as in ``| head -1``:
quietly; stdout closed or full: one line on stderr naming the report).
"""

from __future__ import annotations

from ..calib import Calibration, read_calibration, read_kitti_calib
from .calibration import BatchRectifier, raw_rectification, resolve_calibration
from .command import print_summary, register, run
from .compute import process_pair
from .discovery import (
    FOLDER_PAIRS,
    IMAGE_SUFFIXES,
    PAIR_NAMES,
    SEARCH_DEPTH,
    Discovery,
    discover,
    find_pairs,
)
from .job import FORMATS, RECORD_SUFFIX, STATUSES, BatchOptions, Pair, UsageError
from .records import BatchReport, completed_record
from .runners import EMBEDDED_IN_FLIGHT, LOCK_NAME, run_batch

__all__ = [
    "EMBEDDED_IN_FLIGHT",
    "FOLDER_PAIRS",
    "FORMATS",
    "IMAGE_SUFFIXES",
    "LOCK_NAME",
    "PAIR_NAMES",
    "RECORD_SUFFIX",
    "SEARCH_DEPTH",
    "STATUSES",
    "BatchOptions",
    "BatchRectifier",
    "BatchReport",
    "Calibration",
    "Discovery",
    "Pair",
    "UsageError",
    "completed_record",
    "discover",
    "find_pairs",
    "print_summary",
    "process_pair",
    "raw_rectification",
    "read_calibration",
    "read_kitti_calib",
    "register",
    "resolve_calibration",
    "run",
    "run_batch",
]
