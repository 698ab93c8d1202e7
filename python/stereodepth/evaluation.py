"""The ``stereodepth eval`` command: stereo matchers on scenes with ground truth, scored and timed.

Scenes
    Every sub-folder of DIR that holds a scene (or DIR itself, when it is one), in name order;
    with ``--scene PATTERN``, those whose folder name matches. Only those are read and checked:
    a broken scene that ``--scene`` leaves out does not matter.
    Two layouts are read:

    - ours (``shared/data/stereo``): ``left.png``, ``right.png``, ``disp_gt.npy`` (float
      disparity, NaN where unknown), optional ``mask_nonocc.npy`` (bool) and ``meta.json``
      (``max_disp``);
    - Middlebury 2014 / MiddEval3: ``im0.png``, ``im1.png``, ``disp0GT.pfm`` or ``disp0.pfm``
      (inf where unknown), optional ``mask0nocc.png`` (255 = non-occluded) and ``calib.txt``
      (``ndisp``; its ``width`` and ``height``, where given, must be the images' size).

Disparity range
    Every method searches the same range, from 0 to ``num_disparities - 1`` with
    ``num_disparities = 16 * ceil((D + 1) / 16)`` (OpenCV needs a multiple of 16), where D, the
    largest ground-truth disparity, is ``max_disp`` from ``meta.json``, else ``ndisp - 1`` from
    ``calib.txt``, else the ceiling of the largest finite ground-truth value.
    ``--num-disparities`` (a multiple of 16, at most 4096) overrides it for every scene. A
    declared D (meta.json's or calib.txt's) whose range the ground truth leaves (a value of
    another resolution) is an error naming the scene.

Methods
    ``stereodepth`` (or ``bm``, as ``match`` and ``batch`` call it):
    :func:`stereodepth.block_match` on the images as read (RGB or grey; the matcher
    converts), with its own defaults unless ``--block-size`` / ``--option`` say otherwise.
    ``sgm``: :func:`stereodepth.semi_global_match` with its defaults (``--block-size`` 1 or 3;
    ``--sgm-option KEY=VALUE`` passes its keyword options, as ``--option`` does for
    ``stereodepth``). The time-ratio lines compare each of ours with each peer.
    ``opencv-bm``: ``cv2.StereoBM_create(numDisparities, blockSize)`` (other parameters at
    OpenCV's defaults) on grey uint8 images (``cv2.COLOR_RGB2GRAY``); default block size 9.
    Colour images are read as R, G, B (the order PNG stores); ``--channel-order bgr`` says
    that the files hold B, G, R (an OpenCV array saved by a tool that expected RGB): every
    method then converts to grey as ``cv2.COLOR_BGR2GRAY``.
    ``opencv-sgbm``: ``cv2.StereoSGBM_create(minDisparity=0, numDisparities, blockSize,
    P1=8*bs*bs, P2=32*bs*bs)`` (the usual penalties for one channel; mode ``MODE_SGBM`` and the
    other parameters at OpenCV's defaults) on the same grey images; default block size 5.
    ``opencv-sgbm-3way`` and ``opencv-sgbm-hh``: the same in ``MODE_SGBM_3WAY`` and
    ``MODE_HH`` (the method chooses the mode: ``--opencv-option mode=N`` is refused;
    OpenCV's ``MODE_HH4`` is not offered). ``opencv-sgbm-3way-padded``: ``MODE_SGBM_3WAY``
    on the grey pair padded on the left by ``num_disparities`` columns (each image's first
    column repeated, ``cv2.BORDER_REPLICATE``), the padding cut off the result: OpenCV then
    matches the left band of ``num_disparities - 1`` columns that it otherwise leaves without
    a match, which is how OpenCV users get a disparity there (the peer of our border band);
    the padding is timed.
    OpenCV's int16 output (disparity x 16) becomes float32 / 16 with the values below
    ``minDisparity * 16`` = 0 (no match; OpenCV writes ``(minDisparity - 1) * 16``) as NaN,
    by :func:`stereodepth.from_opencv_disparity`. A raw value outside the searched range,
    neither that hole value (-16) nor in ``0 .. num_disparities * 16 - 1``, is no result of
    matching: it is a hole too, and a note on stderr (and in ``notes`` of ``--json``) names
    the method, block size and scene and says how many pixels held one. That check is not
    timed. StereoBM writes no pixel at all when its valid disparity region
    (``cv2.getValidDisparityROI``) is empty for the images' size, its block size and the
    range, as on images a little wider than the range (20 x 12 px with block size 9 and 16
    disparities; a 384 px wide scene with ``--num-disparities 384``): it returns uninitialised
    memory, in the range as well as outside it, so ``opencv-bm`` is not run there (an ``n/a``
    row, below). Outside a non-empty region it writes its hole value; StereoSGBM writes
    every pixel. OpenCV runs only when ``cv2`` imports; otherwise its methods are
    skipped with a note. ``METHOD:9,15`` (or ``--block-size 9 15``) runs a method with each
    block size and adds a ``best=`` row per scene: the block size with the lowest
    ``--best-by`` metric (bad-2 by default).

Checks
    Every selected scene is read and checked before any is matched (its files, left and right
    images of one size and bit depth, a mask selecting no pixel with ground truth, a declared
    range its ground truth leaves; an ``intensity_range`` in ``--option`` or
    ``--sgm-option``, which is for 16-bit images, with an 8-bit scene), so that a fault in
    the last scene ends the run before the work on the others, not after it.

Scenes an OpenCV method cannot take
    OpenCV's StereoBM and StereoSGBM take 8-bit images only. On a scene whose images are not
    8-bit (16-bit PNGs) the OpenCV methods are not run: each of their rows there reads
    ``n/a`` (``not_applicable`` in ``--json``, with the reason), a note on stderr names the
    methods and scenes, and every other method and scene is scored as usual. The ``mean``
    row of a variant scored on K of the run's N scenes reads ``mean K/N``, with a line under
    the table saying that its means are over those K scenes only (``scenes`` and
    ``scenes_not_applicable`` of its ``means`` entry in ``--json``): means over different
    scene sets are not comparable. Time ratios are over the scenes both methods ran. The exit
    status is 0 when anything was scored; when no method can run on any scene (only OpenCV
    methods, every scene 16-bit), it is an error before any matching (exit status 2).

    A scene whose images an OpenCV matcher's ``compute`` refuses (a ``cv2.error``: images too
    small for the block size and search range, say) is the same: that variant's row there is
    ``n/a`` with OpenCV's explanation as the reason (or, for ``opencv-bm``, that its valid
    disparity region is empty), the means of the method are over its
    other scenes (``mean K/N``), and a note on stderr says so, after the matching. A method run
    at several block sizes has no ``best=`` row on a scene where one of them is n/a. The
    lines under the table name such a method's variants with their block sizes
    (``opencv-bm:15``, ``opencv-bm:best`` for its best= rows), the stderr notes as
    ``opencv-bm (block 15)``. When
    nothing was scored at all, it is an error (exit status 2) naming the first refusal.
    Anything else that fails (our matchers' errors, OpenCV refusing its parameters or running
    out of memory) ends the run, naming the scene and method.

Timing
    Each method is run once to warm up, then ``--repeat`` times (default 3); the time is the
    median. It covers the whole conversion from the images as read to a float disparity map
    with NaN holes (for OpenCV: grey conversion, matching and the x16 decoding).
    ``ns/(px*d)`` is that time divided by width x height x num_disparities. Threads: ``--threads``
    (default: every core this process may use) for both the stereodepth matcher and OpenCV
    (``cv2.setNumThreads``; restored afterwards).

Scores
    :func:`stereodepth.metrics.evaluate` over the non-occluded pixels with ground truth where the
    scene has a mask (``region`` nonocc), else over all pixels with ground truth (``all``);
    ``--no-mask`` always uses all. ``D1`` is KITTI's outlier rate (off by more than 3 px and
    5 %; holes count), ``d1`` and ``d1_est`` in ``--json``. Percentages in the tables,
    fractions in ``--json``. The ``mean`` rows average each score over the scenes the
    variant was scored on (every scene weighs the same) and the times; their ``ns/(px*d)`` is
    the total time over the total work. The ``--json`` object also records the options given
    (``options``, ``sgm_options``, ``opencv_options``: each a dict of the ``KEY=VALUE`` pairs
    after conversion, empty when none was given) and the names of the scenes (``scenes``).
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import os
import re
import statistics
import sys
import time
import tokenize
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from . import _validate as check
from .cli import KeyValueOnce, key_value_option, path_arg
from .depth import from_opencv_disparity
from .matching import MAX_BLOCK_SIZE, MAX_NUM_DISPARITIES
from .metrics import DisparityMetrics, evaluate, negative_ground_truth

__all__ = [
    "METHODS",
    "EvalResult",
    "NotApplicable",
    "Scene",
    "Variant",
    "find_scenes",
    "format_not_applicable",
    "format_table",
    "num_disparities_for",
    "register",
    "run",
]

#: The matchers ``stereodepth eval`` knows, and the block size each uses when none is given
#: (None: the matcher's own default).
METHODS: dict[str, int | None] = {
    "stereodepth": None,
    "sgm": None,
    "opencv-bm": 9,
    "opencv-sgbm": 5,
    "opencv-sgbm-3way": 5,
    "opencv-sgbm-hh": 5,
    "opencv-sgbm-3way-padded": 5,
}
_OPENCV_METHODS = (
    "opencv-bm",
    "opencv-sgbm",
    "opencv-sgbm-3way",
    "opencv-sgbm-hh",
    "opencv-sgbm-3way-padded",
)
#: Options of stereodepth.block_match that eval sets itself.
_RESERVED_OPTIONS = {
    "num_disparities": "set per scene from the ground truth; use --num-disparities",
    "min_disparity": "eval searches from 0",
    "block_size": "use --block-size or METHOD:SIZE",
    "threads": "use --threads",
    "return_confidence": "eval scores the disparity only",
    "channel_order": "use --channel-order",
}
_BEST_BY = (
    "bad_0_5",
    "bad_1",
    "bad_2",
    "bad_4",
    "bad_0_5_est",
    "bad_1_est",
    "bad_2_est",
    "bad_4_est",
    "d1",
    "d1_est",
    "avgerr",
    "rms",
)


def _usage_error(message: str) -> Exception:
    """stereodepth.cli.UsageError (imported late: cli imports this module)."""
    from .cli import UsageError

    return UsageError(message)


# --------------------------------------------------------------------------------------------
# Scenes


@dataclass(frozen=True)
class Scene:
    """A stereo pair with ground truth on disk.

    ``max_disparity_px`` is the largest ground-truth disparity as declared by the scene's
    ``meta.json`` (``max_disp``) or ``calib.txt`` (``ndisp - 1``); None when neither gives it.
    ``calib_size`` is (width, height) of the images a Middlebury ``calib.txt`` describes
    (its ``width`` and ``height``), None without one; :meth:`load` checks the images' size
    against it.
    """

    name: str
    path: Path
    left_path: Path
    right_path: Path
    gt_path: Path
    mask_path: Path | None
    max_disparity_px: float | None
    calib_size: tuple[int, int] | None = None

    def load(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """(left, right, gt, mask): the images as read by :func:`stereodepth.io.read_image`,
        the float ground truth (NaN or inf where unknown) and the bool mask or None. Raises
        ValueError naming the file when a part is malformed, the shapes or the images' bit
        depths (dtypes) disagree, or when
        the ground truth has a negative finite value (:mod:`stereodepth.metrics`' rule: every
        method searches from 0, and neither KITTI nor Middlebury has negative disparities)."""
        from .io import read_image, read_pfm

        left = read_image(self.left_path)
        right = read_image(self.right_path)
        if left.shape != right.shape:
            raise ValueError(
                f"scene {self.name}: left and right images must have the same shape, "
                f"got {left.shape} and {right.shape}"
            )
        if left.dtype != right.dtype:
            # Every matcher refused the pair, only when this scene's turn came.
            raise ValueError(
                f"scene {self.name}: left and right images must have the same bit depth, got "
                f"{left.dtype} ({self.left_path.name}) and {right.dtype} ({self.right_path.name})"
            )
        size = (left.shape[1], left.shape[0])
        if self.calib_size is not None and self.calib_size != size:
            # Its ndisp (the search range) is in that resolution's pixels: a quarter-size
            # calib.txt beside full-size images searched a quarter of the disparities.
            raise ValueError(
                f"{self.path / 'calib.txt'}: it is for {self.calib_size[0]}x"
                f"{self.calib_size[1]} px images, {self.left_path.name} is {size[0]}x{size[1]}"
                " px: use the calib.txt of these images"
            )
        gt = read_pfm(self.gt_path) if self.gt_path.suffix == ".pfm" else _load_npy(self.gt_path)
        if gt.dtype.kind != "f" or gt.shape != left.shape[:2]:
            raise ValueError(
                f"{self.gt_path}: ground truth must be a float array of the image's shape "
                f"{left.shape[:2]}, got {gt.dtype} {gt.shape}"
            )
        problem = negative_ground_truth(gt)  # the matchers here search from 0
        if problem is not None:
            raise ValueError(f"{self.gt_path}: ground truth {problem}")
        mask = None
        if self.mask_path is not None:
            if self.mask_path.suffix == ".png":
                # Middlebury's masks are 8-bit grey, 255 = non-occluded: a 16-bit one (65535)
                # gave an empty mask, nothing scored; a colour one a 3-channel "mask".
                image = read_image(self.mask_path)
                if image.dtype != np.uint8 or image.ndim != 2:
                    kind = "16-bit" if image.dtype == np.uint16 else "colour"
                    raise ValueError(
                        f"{self.mask_path}: a Middlebury mask must be an 8-bit grey PNG "
                        f"(255 = non-occluded), got a {kind} image of shape {image.shape}"
                    )
                mask = image == 255
            else:
                mask = _load_npy(self.mask_path)
            if mask.dtype != np.bool_ or mask.shape != left.shape[:2]:
                raise ValueError(
                    f"{self.mask_path}: mask must be a bool array of the image's shape "
                    f"{left.shape[:2]}, got {mask.dtype} {mask.shape}"
                )
        return left, right, gt, mask


def _load_npy(path: Path) -> np.ndarray:
    """A ``.npy`` array (no pickles), or ValueError naming the file and what is wrong with it.

    The file must hold exactly the bytes its header's dtype and shape give after the header:
    numpy read a padded file without a word (the stray bytes ignored), took a truncated one's
    header at its word (a damaged shape made it allocate terabytes: MemoryError), raised
    tokenize's TokenError for a damaged header, EOFError for an empty file, and named no file
    in its other errors."""
    try:
        with open(path, "rb") as f:
            head = f.read(6)
            if head == b"\x93NUMPY":
                _check_npy_size(path, f)
    except OSError as exc:
        raise ValueError(f"{path}: not a readable .npy array ({exc})") from None
    # numpy takes any other file for a pickle, and says it "contains pickled data".
    if head and head != b"\x93NUMPY" and not head.startswith(b"PK"):
        raise ValueError(f"{path}: not a readable .npy array (no NumPy header: it starts {head!r})")
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, EOFError, OSError) as exc:
        raise ValueError(f"{path}: not a readable .npy array ({exc})") from None
    if not isinstance(arr, np.ndarray):  # an .npz archive under a .npy name
        arr.close()
        raise ValueError(f"{path}: not a .npy array (an .npz archive)")
    return arr


def _check_npy_size(path: Path, f: BinaryIO) -> None:
    """Reads the header of the open ``.npy`` file ``f`` and checks the file's size against
    it: ValueError naming ``path`` for a header numpy cannot parse, a negative dimension, or
    fewer or more bytes after the header than its dtype and shape give. An array of Python
    objects (pickled: no fixed size) is left to np.load, which refuses it."""
    from numpy.lib import format as npy

    f.seek(0)
    try:
        version = npy.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = npy.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, _, dtype = npy.read_array_header_2_0(f)
        else:  # 3.0 is for structured arrays with non-Latin-1 field names, never read here
            raise ValueError(
                f"format version {version[0]}.{version[1]}, expected 1.0 or 2.0 "
                "(a plain float or bool array)"
            )
    except (ValueError, SyntaxError, tokenize.TokenError, EOFError) as exc:
        # TokenError's str is its args tuple: ('EOF in multi-line statement', (2, 0))
        reason = exc.args[0] if isinstance(exc, tokenize.TokenError) and exc.args else exc
        raise ValueError(f"{path}: not a readable .npy array (its header: {reason})") from None
    if dtype.hasobject:
        return
    if any(n < 0 for n in shape):
        raise ValueError(f"{path}: not a readable .npy array (its header gives shape {shape})")
    header = f.tell()
    held = os.fstat(f.fileno()).st_size - header
    data = math.prod(shape) * dtype.itemsize
    if held != data:
        what = "truncated" if held < data else f"followed by {held - data} stray byte(s)"
        raise ValueError(
            f"{path}: .npy array {what}: its header gives {dtype} {shape}, {data} bytes of "
            f"data, but the file holds {held} bytes after its {header}-byte header"
        )


def _meta_max_disparity(path: Path) -> float | None:
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read JSON: {exc}") from exc
    if not isinstance(meta, dict):  # a list or a number was read as "no max_disp"
        raise ValueError(f"{path}: must be a JSON object, got {type(meta).__name__}")
    value = meta.get("max_disp")
    if value is None:
        return None
    number = None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        try:
            number = float(value)
        except OverflowError:  # a JSON integer beyond a double's range
            number = None
    if number is None or not (math.isfinite(number) and number >= 0):
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
        raise ValueError(f"{path}: max_disp must be a finite number >= 0, got {shown}")
    return number


def _require_right(path: Path, right: str, left: str, gt: str) -> None:
    """A folder with a scene's left image and ground truth but not its right image is an
    incomplete scene: refused before any scene runs (it was taken as a scene, and the whole
    run failed on it with exit status 1 after the scenes before it)."""
    if not (path / right).is_file():
        raise ValueError(
            f"{str(path)!r} holds {left} and {gt} but not {right}: a scene folder holds all "
            "three (add it, or move the folder out of DIR)"
        )


def _holds_scene(path: Path) -> bool:
    """Whether ``path`` holds a scene's left image and ground truth (either layout), its other
    files neither read nor checked: :func:`_scene_at` does that, for the selected scenes."""
    if (path / "left.png").is_file() and (path / "disp_gt.npy").is_file():
        return True
    gts = ("disp0GT.pfm", "disp0.pfm")
    return (path / "im0.png").is_file() and any((path / n).is_file() for n in gts)


def _scene_at(path: Path) -> Scene | None:
    if (path / "left.png").is_file() and (path / "disp_gt.npy").is_file():
        _require_right(path, "right.png", "left.png", "disp_gt.npy")
        mask = path / "mask_nonocc.npy"
        meta = path / "meta.json"
        return Scene(
            name=path.name,
            path=path,
            left_path=path / "left.png",
            right_path=path / "right.png",
            gt_path=path / "disp_gt.npy",
            mask_path=mask if mask.is_file() else None,
            max_disparity_px=_meta_max_disparity(meta) if meta.is_file() else None,
        )
    gts = [path / n for n in ("disp0GT.pfm", "disp0.pfm") if (path / n).is_file()]
    if (path / "im0.png").is_file() and gts:
        _require_right(path, "im1.png", "im0.png", gts[0].name)
        max_disp = None
        calib_size = None
        if (path / "calib.txt").is_file():
            from .calib import read_middlebury_calib

            calib = read_middlebury_calib(path / "calib.txt")
            max_disp = None if calib.ndisp is None else float(calib.ndisp - 1)
            if calib.width_px and calib.height_px:
                calib_size = (calib.width_px, calib.height_px)
        mask = path / "mask0nocc.png"
        return Scene(
            name=path.name,
            path=path,
            left_path=path / "im0.png",
            right_path=path / "im1.png",
            gt_path=gts[0],
            mask_path=mask if mask.is_file() else None,
            max_disparity_px=max_disp,
            calib_size=calib_size,
        )
    return None


def find_scenes(root: str | os.PathLike[str], patterns: Sequence[str] = ()) -> list[Scene]:
    """The scenes in ``root`` (its sub-folders in name order, or ``root`` itself when it is a
    scene), keeping those whose folder name matches one of the shell ``patterns`` if any are
    given. Only the kept scenes are read (``meta.json``, ``calib.txt``) and checked. Raises
    ValueError when ``root`` is not a folder (or is empty: not the current folder), a kept
    folder holds a scene's left image and ground truth but not its right image or a
    malformed ``meta.json`` / ``calib.txt``, or nothing matches, and TypeError for a ``root``
    that is not a str or os.PathLike or ``patterns`` that are not a sequence of str (a str
    alone was taken as its characters, and a ``*`` among them matched every scene)."""
    from .io import _as_path

    base = _as_path(root, "root")
    if isinstance(patterns, (str, bytes)) or not all(isinstance(p, str) for p in patterns):
        hint = f", such as [{patterns!r}]" if isinstance(patterns, str) else ""
        raise TypeError(
            f"patterns must be a sequence of shell patterns (str){hint}, got "
            f"{type(patterns).__name__} {patterns!r}"
        )
    if not base.is_dir():
        raise ValueError(f"DIR must be a folder of scenes, got {str(base)!r} (not a folder)")
    # Only the selected scenes are read (meta.json, calib.txt) and checked: a broken scene
    # that --scene left out ended the run.
    if _holds_scene(base):
        found = [base]
    else:
        found = [p for p in sorted(base.iterdir()) if p.is_dir() and _holds_scene(p)]
    if not found:
        raise ValueError(
            f"no scene in {str(base)!r}: a scene folder holds left.png, right.png and "
            "disp_gt.npy, or im0.png, im1.png and disp0GT.pfm / disp0.pfm"
        )
    if patterns:
        kept = [f for f in found if any(fnmatch.fnmatchcase(f.name, p) for p in patterns)]
        if not kept:
            raise ValueError(
                f"--scene {' '.join(patterns)} matches no scene in {str(base)!r}; "
                f"there are: {', '.join(f.name for f in found)}"
            )
        found = kept
    return [scene for folder in found if (scene := _scene_at(folder)) is not None]


def num_disparities_for(max_disparity_px: float) -> int:
    """``16 * ceil((D + 1) / 16)`` for D = ``ceil(max_disparity_px)``: the smallest multiple of
    16 whose search range ``0 .. num_disparities - 1`` reaches the largest disparity.

    Takes any real number, numpy's included (the largest value of a float32 ground truth is
    a numpy.float32); raises TypeError for another type (a bool, a str) and ValueError for a
    negative or non-finite value."""
    d = check.non_negative("max_disparity_px", max_disparity_px)
    return 16 * math.ceil((math.ceil(d) + 1) / 16)


# --------------------------------------------------------------------------------------------
# Methods


@dataclass(frozen=True)
class Variant:
    """One method at one block size (None: the method's default)."""

    method: str
    block_size: int | None


Matcher = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _stereodepth_factory(
    threads: int,
    options: dict[str, Any],
    channel_order: str = "rgb",
    sgm_options: dict[str, Any] | None = None,
) -> Callable[[Variant, int], Matcher]:
    from stereodepth.matching import StereoMatcher
    from stereodepth.semi_global import SemiGlobalMatcher

    def make(variant: Variant, num_disparities: int) -> Matcher:
        kwargs = dict(options) if variant.method == "stereodepth" else dict(sgm_options or {})
        if variant.block_size is not None:
            kwargs["block_size"] = variant.block_size
        # Made once per scene and reused across the timed runs, as the OpenCV matchers are.
        cls = SemiGlobalMatcher if variant.method == "sgm" else StereoMatcher
        matcher = cls(
            num_disparities=num_disparities,
            min_disparity=0,
            threads=threads,
            channel_order=channel_order,
            **kwargs,
        )

        def match(left: np.ndarray, right: np.ndarray) -> np.ndarray:
            return np.asarray(matcher.compute(left, right))

        return match

    return make


#: The start of an OpenCV error message: its version, source location and "error:"
#: (``OpenCV(4.10.0) /path/stereobm.cpp:1172: error: ``; ``OpenCV(5.0.0) :-1: error: `` for
#: the bindings' own).
_CV_LOCATION = re.compile(r"^OpenCV\([^)]*\)\s*.*?:-?\d+:\s*error:\s*")


def _cv_message(exc: BaseException) -> str:
    """An OpenCV error on one line, without its version and source location: the code and
    kind with the failed check or explanation and the function (``(-215:Assertion failed)
    left.depth() == CV_8U in function 'compute'``), then, after ": ", the lines OpenCV adds
    below it without their ``>`` marks (a CV_Check's explanation and values, the overloads
    tried), joined by spaces. Only the last line was kept: "'params.calcSADWindowSize().width/2'
    is 2" of SGBM's "Your input images are too small for your window size and max disparity
    ..." error. A message of another form is kept whole, on one line."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    if not lines:
        return type(exc).__name__
    first = _CV_LOCATION.sub("", lines[0]) or lines[0]
    rest = [text for line in lines[1:] if (text := line.lstrip(">").strip())]
    return f"{first}: {' '.join(rest)}" if rest else first


def _camel(key: str) -> str:
    return "".join(part[:1].upper() + part[1:] for part in key.split("_"))


def _opencv_factory(
    cv2: Any,
    options: dict[str, Any],
    channel_order: str = "rgb",
    texts: dict[str, str] | None = None,
) -> Callable[[Variant, int], Matcher]:
    to_grey = cv2.COLOR_BGR2GRAY if channel_order == "bgr" else cv2.COLOR_RGB2GRAY

    def grey(img: np.ndarray) -> np.ndarray:
        if img.dtype != np.uint8:
            raise ValueError(f"{_OPENCV_8_BIT}, got {img.dtype}")
        if img.ndim == 3:
            return np.asarray(cv2.cvtColor(img, to_grey))
        return img

    def make(variant: Variant, num_disparities: int) -> Matcher:
        bs = variant.block_size
        if bs is None:
            raise ValueError("OpenCV's matchers need a block size, got None")
        try:
            if variant.method == "opencv-bm":
                matcher = cv2.StereoBM_create(numDisparities=num_disparities, blockSize=bs)
            else:
                modes = {
                    "opencv-sgbm": cv2.STEREO_SGBM_MODE_SGBM,
                    "opencv-sgbm-3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
                    "opencv-sgbm-hh": cv2.STEREO_SGBM_MODE_HH,
                    "opencv-sgbm-3way-padded": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
                }
                matcher = cv2.StereoSGBM_create(
                    minDisparity=0,
                    numDisparities=num_disparities,
                    blockSize=bs,
                    P1=8 * bs * bs,
                    P2=32 * bs * bs,
                    mode=modes[variant.method],
                )
        except cv2.error as exc:
            raise ValueError(f"OpenCV rejected the parameters: {_cv_message(exc)}") from exc
        for key, value in options.items():
            setter = getattr(matcher, "set" + _camel(key), None)
            if setter is not None:
                try:
                    setter(value)
                except (cv2.error, TypeError) as exc:
                    raise ValueError(
                        f"--opencv-option {_as_typed(key, value, texts)} rejected by OpenCV: "
                        f"{_cv_message(exc)}"
                    ) from exc

        pad = num_disparities if variant.method == "opencv-sgbm-3way-padded" else 0

        def padded(img: np.ndarray) -> np.ndarray:
            g = grey(img)
            if pad == 0:
                return g
            return np.asarray(cv2.copyMakeBorder(g, 0, 0, pad, 0, cv2.BORDER_REPLICATE))

        checked: set[tuple[int, ...]] = set()  # image shapes whose BM region is not empty

        def compute(left: np.ndarray, right: np.ndarray) -> np.ndarray:
            left, right = padded(left), padded(right)
            if variant.method == "opencv-bm" and left.shape not in checked:
                # once per shape, not in every timed call
                _check_bm_region(cv2, left.shape[1], left.shape[0], num_disparities, bs)
                checked.add(left.shape)
            try:
                return np.asarray(matcher.compute(left, right))[:, pad:]
            except cv2.error as exc:
                if getattr(exc, "code", None) == cv2.Error.StsNoMem:  # not about the input
                    raise ValueError(f"OpenCV failed: {_cv_message(exc)}") from exc
                raise _Refused(f"OpenCV refused the images: {_cv_message(exc)}") from exc

        return _OpenCVMatch(compute, num_disparities)

    return make


def _check_bm_region(cv2: Any, width: int, height: int, num_disparities: int, bs: int) -> None:
    """:class:`_Refused` when StereoBM's valid disparity region
    (``cv2.getValidDisparityROI``) is empty for ``width`` x ``height`` px images, block size
    ``bs`` and ``num_disparities`` from 0: StereoBM then writes none of its output and returns
    what the memory held (a width between about ``num_disparities`` and ``num_disparities +
    bs - 2``: 20 x 12 px with 16 disparities and block 9; Tsukuba, 384 px wide, with 384),
    garbage within the searched range as well as outside it. Where the region is not empty,
    StereoBM writes its hole value (-16) outside it. StereoSGBM writes every pixel."""
    whole = (0, 0, width, height)
    _, _, w, h = cv2.getValidDisparityROI(whole, whole, 0, num_disparities, bs)
    if w <= 0 or h <= 0:
        # No sizes in the reason: the scenes and variants it holds for share a line.
        raise _Refused(
            "OpenCV's valid disparity region is empty for this size, window and range "
            "(cv2.getValidDisparityROI): StereoBM leaves its output unwritten"
        )


class _Refused(Exception):
    """An OpenCV matcher's ``compute`` refused a scene's images (a cv2.error): images too
    small for its block size and search range, say; or eval did not run it on images it
    would leave its output unwritten for (StereoBM's valid disparity region empty). The
    args hold the reason."""


class _OpenCVMatch:
    """An OpenCV matcher's ``compute`` (int16, disparity x 16, searching from 0) decoded by
    :func:`stereodepth.from_opencv_disparity`; :meth:`beyond_range` then tells which pixels of
    the last result held a raw value outside the searched range."""

    def __init__(self, compute: Callable[[np.ndarray, np.ndarray], np.ndarray], num_disp: int):
        self._compute = compute
        self._num_disparities = num_disp
        self._raw: np.ndarray | None = None

    def __call__(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        self._raw = self._compute(left, right)
        # eval searches from 0 (minDisparity=0): holes are the raw values below 0.
        return from_opencv_disparity(self._raw, min_disparity=0)

    def beyond_range(self) -> tuple[np.ndarray, str]:
        """The pixels of the last result whose raw value is neither a disparity of the
        searched range ``0 .. (num_disparities * 16 - 1)`` nor OpenCV's hole ``-16``
        (minDisparity 0), and the span of those values ("" when there is none): not a
        result of matching. (StereoBM's unwritten output, with an empty valid region, is
        not run at all: :func:`_check_bm_region`; this is the check of what remains.)"""
        assert self._raw is not None
        raw = self._raw
        bad = ((raw < 0) & (raw != -16)) | (raw >= self._num_disparities * 16)
        span = f"{int(raw[bad].min())} .. {int(raw[bad].max())}" if bad.any() else ""
        return bad, span


#: The largest odd SGBM block size whose P2 (32 * size**2) fits OpenCV's int.
_SGBM_MAX_BLOCK_SIZE = 8191

_C_INT = (-(2**31), 2**31 - 1)


def _at_least(low: int) -> tuple[Callable[[int], bool], str]:
    """From ``low`` up to the largest C int: OpenCV's setters take an int."""
    return _within(low, _C_INT[1])


def _within(low: int, high: int) -> tuple[Callable[[int], bool], str]:
    return (lambda v: low <= v <= high), f"an integer in {low}..{high}"


#: What OpenCV takes for each ``--opencv-option`` (its setter's value), by matcher class:
#: ``compute`` refuses some values (StereoBM's pre-filter) and silently replaces others
#: (StereoSGBM's negative uniqueness ratio by 10, a P1 <= 0 by 2, a P2 <= P1 by P1 + 1);
#: all are refused here (P2 against P1 by :func:`_check_opencv_options`, each the one given
#: or eval's for the block size).
_OPENCV_OPTION_RULES: dict[str, dict[str, tuple[Callable[[int], bool], str]]] = {
    "bm": {
        "pre_filter_type": (
            lambda v: v in (0, 1),
            "0 (PREFILTER_NORMALIZED_RESPONSE) or 1 (PREFILTER_XSOBEL)",
        ),
        "pre_filter_size": (lambda v: v % 2 == 1 and 5 <= v <= 255, "an odd integer in 5..255"),
        "pre_filter_cap": _within(1, 63),
        "texture_threshold": _at_least(0),
        "uniqueness_ratio": _at_least(0),
        "speckle_window_size": _at_least(0),
        "speckle_range": _at_least(0),
        "disp12_max_diff": _within(*_C_INT),
        "smaller_block_size": _at_least(0),
    },
    "sgbm": {
        "pre_filter_cap": _at_least(1),
        "uniqueness_ratio": _at_least(0),
        "speckle_window_size": _at_least(0),
        "speckle_range": _at_least(0),
        "disp12_max_diff": _within(*_C_INT),
        "p1": _at_least(1),
        "p2": _at_least(1),
    },
}
#: ``--opencv-option mode=N`` is refused: the method name chooses StereoSGBM's mode (a mode
#: set on every selected matcher ran them all in one mode under their own names).
_OPENCV_MODE_REFUSED = (
    "the method chooses OpenCV's SGBM mode: opencv-sgbm (MODE_SGBM), opencv-sgbm-hh "
    "(MODE_HH), opencv-sgbm-3way and opencv-sgbm-3way-padded (MODE_SGBM_3WAY); MODE_HH4 is "
    "not offered"
)


def _check_opencv_options(
    options: dict[str, Any], variants: Sequence[Variant], texts: dict[str, str] | None = None
) -> None:
    """Each ``--opencv-option`` value checked against what the selected OpenCV matchers
    (``variants``) take, before any scene is read: one line naming the option as typed
    (``texts``: key to the text given) and the matcher (``pre_filter_cap=64`` reached
    OpenCV). P2 must be above P1, each the one given or eval's for the variant's block size
    (8 and 32 x its square): OpenCV replaced a smaller P2 by P1 + 1 without a word."""
    methods = {v.method for v in variants}
    kinds = {("bm" if m == "opencv-bm" else "sgbm"): m for m in sorted(methods)}
    for key, value in options.items():
        for kind, method in kinds.items():
            rules = _OPENCV_OPTION_RULES[kind]
            if key not in rules:
                continue  # a setter of the other matcher, or unknown: checked by the caller
            ok, what = rules[key]
            is_int = isinstance(value, int) and not isinstance(value, bool)
            if not (is_int and _C_INT[0] <= value <= _C_INT[1] and ok(value)):
                raise _usage_error(
                    f"--opencv-option {_as_typed(key, value, texts)} rejected by {method}: "
                    f"{key} must be {what}"
                )
    p1, p2 = options.get("p1"), options.get("p2")
    if p1 is None and p2 is None:
        return
    for v in sorted(variants, key=lambda v: (v.method, v.block_size or 0)):
        bs = v.block_size
        if v.method == "opencv-bm" or bs is None:
            continue
        eval_p1, eval_p2 = 8 * bs * bs, 32 * bs * bs
        if p1 is not None and p2 is not None:
            if not p2 > p1:
                raise _usage_error(
                    f"--opencv-option {_as_typed('p2', p2, texts)}: OpenCV's P2 must be > P1, "
                    f"got {_as_typed('p1', p1, texts)} (OpenCV would use P2 = P1 + 1 instead)"
                )
            return
        if p2 is not None and not p2 > eval_p1:
            raise _usage_error(
                f"--opencv-option {_as_typed('p2', p2, texts)}: OpenCV's P2 must be > P1, and "
                f"eval's P1 for {v.method}:{bs} is {eval_p1} (8 x {bs} x {bs}): give p1 too, "
                "or a larger p2 (OpenCV would use P2 = P1 + 1 instead)"
            )
        if p1 is not None and not eval_p2 > p1:
            raise _usage_error(
                f"--opencv-option {_as_typed('p1', p1, texts)}: OpenCV's P2 must be > P1, and "
                f"eval's P2 for {v.method}:{bs} is {eval_p2} (32 x {bs} x {bs}): give p2 too, "
                "or a smaller p1 (OpenCV would use P2 = P1 + 1 instead)"
            )


def _check_block_size(variant: Variant) -> None:
    bs = variant.block_size
    if bs is None:
        return
    if variant.method == "opencv-bm" and not (bs % 2 == 1 and 5 <= bs <= 255):
        raise ValueError(f"block size of opencv-bm must be an odd integer in 5..255, got {bs}")
    if variant.method.startswith("opencv-sgbm") and not (
        bs % 2 == 1 and 1 <= bs <= _SGBM_MAX_BLOCK_SIZE
    ):
        # eval passes P2 = 32 * block size**2: 9999 was "integer won't fit into a C int",
        # from OpenCV, naming no parameter, once the scenes were read.
        raise ValueError(
            f"block size of {variant.method} must be an odd integer in "
            f"1..{_SGBM_MAX_BLOCK_SIZE} (eval gives OpenCV P2 = 32 x its square, a C int), "
            f"got {bs}"
        )
    if variant.method == "stereodepth":
        # The largest over the costs (census); a smaller limit of cost=sad is the matcher's.
        top = max(MAX_BLOCK_SIZE.values())
        if not (bs % 2 == 1 and 3 <= bs <= top):
            raise ValueError(
                f"block size of stereodepth must be an odd integer in 3..{top}, got {bs}"
            )
    if variant.method == "sgm" and bs not in (1, 3):
        raise ValueError(f"block size of sgm must be 1 or 3, got {bs}")


# --------------------------------------------------------------------------------------------
# Running and scoring


@dataclass(frozen=True)
class EvalResult:
    """One method at one block size on one scene. ``best`` marks the per-scene best row of a
    method run at several block sizes (a copy of that block size's row)."""

    scene: str
    variant: Variant
    num_disparities: int
    width: int
    height: int
    region: str  # "nonocc" (the scene's mask) or "all" (every pixel with ground truth)
    metrics: DisparityMetrics
    times_s: tuple[float, ...] = field(repr=False)
    best: bool = False

    @property
    def time_s(self) -> float:
        """The median of the timed runs."""
        return float(statistics.median(self.times_s))

    @property
    def work(self) -> int:
        """Pixels x disparities searched."""
        return self.width * self.height * self.num_disparities

    @property
    def ns_per_px_disparity(self) -> float:
        return self.time_s * 1e9 / self.work

    def as_dict(self) -> dict[str, Any]:
        return {
            "scene": self.scene,
            "method": self.variant.method,
            "block_size": self.variant.block_size,
            "best": self.best,
            "num_disparities": self.num_disparities,
            "width": self.width,
            "height": self.height,
            "region": self.region,
            "metrics": self.metrics.as_dict(),
            "time_s": self.time_s,
            "times_s": list(self.times_s),
            "ns_per_px_disparity": self.ns_per_px_disparity,
        }


@dataclass(frozen=True)
class NotApplicable:
    """One method at one block size that eval did not run on one scene, and why: OpenCV's
    matchers on a scene whose images are not 8-bit, or whose images OpenCV refused. It
    stands for that row in the table (``n/a``), and the method's means are over its other
    scenes."""

    scene: str
    variant: Variant
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return {
            "scene": self.scene,
            "method": self.variant.method,
            "block_size": self.variant.block_size,
            "reason": self.reason,
        }


#: A row of eval's results: a scored variant on a scene, or one not run there.
Row = EvalResult | NotApplicable

#: What OpenCV's matchers take: 8-bit images only (``CV_8UC1``; eval converts colour to grey).
_OPENCV_8_BIT = "OpenCV's StereoBM and StereoSGBM take 8-bit images only"


def _not_applicable(
    scene: str, variants: Sequence[Variant], image: np.ndarray
) -> list[NotApplicable]:
    """The variants that cannot run on a scene whose images are like ``image``: the OpenCV
    methods on images that are not 8-bit (16-bit PNGs, which stereodepth and sgm take)."""
    if image.dtype == np.uint8:
        return []
    reason = f"{_OPENCV_8_BIT}, got {image.dtype}"
    return [NotApplicable(scene, v, reason) for v in variants if v.method in _OPENCV_METHODS]


def _timed(
    match: Matcher, left: np.ndarray, right: np.ndarray, repeat: int
) -> tuple[np.ndarray, tuple[float, ...]]:
    out = match(left, right)  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = match(left, right)
        times.append(time.perf_counter() - t0)
    return out, tuple(times)


def _count(n: int, noun: str) -> str:
    """``n`` and ``noun``, plural unless ``n`` is 1: "1 pixel", "3 pixels"."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _with_best(rows: list[Row], best_by: str) -> list[Row]:
    """Adds, after the rows of each method run at several block sizes, a copy of the best;
    none on a scene where one of them was not run (:class:`NotApplicable`): the best of
    some of the block sizes only is not the best of them all, and the scene counts among
    those the ``best`` rows' means leave out."""
    out: list[Row] = []
    i = 0
    while i < len(rows):
        j = i
        while j < len(rows) and rows[j].variant.method == rows[i].variant.method:
            j += 1
        group = rows[i:j]
        out += group
        scored = _scored(group)
        if len(group) > 1 and len(scored) == len(group):

            def key(r: EvalResult) -> tuple[float, int]:
                v = getattr(r.metrics, best_by)
                return (math.inf if math.isnan(v) else v, r.variant.block_size or 0)

            out.append(replace(min(scored, key=key), best=True))
        i = j
    return out


def _scene_inputs(
    scene: Scene,
    variants: Sequence[Variant],
    *,
    num_disparities: int | None,
    use_mask: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, int]:
    """The scene's images, ground truth, mask (None with ``use_mask`` false) and search range,
    checked: ValueError naming the scene for anything that would fail or score nothing. Run
    over every scene before any is matched, so a fault in the last scene is reported before
    the work on the others, not after it (their results were lost with it)."""
    left, right, gt, mask = scene.load()
    if num_disparities is None:
        max_disp = scene.max_disparity_px
        if max_disp is None:
            finite = gt[np.isfinite(gt)]
            if finite.size == 0:
                raise ValueError(f"scene {scene.name}: the ground truth has no finite value")
            max_disp = max(float(finite.max()), 0.0)
            source = f"the ground truth's largest disparity, {max_disp:g} px,"
        elif scene.left_path.name == "left.png":
            source = f"meta.json's max_disp={max_disp:g}"
        else:  # Middlebury: max_disp is ndisp - 1
            source = f"calib.txt's ndisp={max_disp + 1:g}"
        num_disparities = num_disparities_for(max_disp)
        # In float64: a huge max_disp (meta.json's 1e39) made numpy cast the Python int to
        # the float32 of gt, with overflow warnings on stderr before the error.
        with np.errstate(invalid="ignore"):
            beyond = np.isfinite(gt) & (gt > np.float64(num_disparities - 1))
        nd_text = f"{num_disparities}" if num_disparities < 10**9 else f"{num_disparities:.4g}"
        if beyond.any():
            # A max_disp or ndisp of another resolution (half-size beside full-size images)
            # searched a range the true disparities leave: every method scored badly, exit 0.
            raise ValueError(
                f"scene {scene.name}: the ground truth reaches {float(gt[beyond].max()):g} px "
                f"({_count(int(beyond.sum()), 'pixel')} beyond the search range 0 .. "
                f"{num_disparities - 1} that {source} gives): correct it, or give "
                "--num-disparities"
            )
        if num_disparities > check.MAX_NATIVE_INT:  # OpenCV's numDisparities is a C int
            raise ValueError(
                f"scene {scene.name}: {source} needs {nd_text} disparities, more than any "
                "matcher searches: correct it, or give --num-disparities"
            )
        ours = any(v.method in ("stereodepth", "sgm") for v in variants)
        if ours and num_disparities > MAX_NUM_DISPARITIES:  # the matcher's error named no source
            raise ValueError(
                f"scene {scene.name}: {source} needs {nd_text} "
                f"disparities, more than the matchers search ({MAX_NUM_DISPARITIES}): give "
                "--num-disparities"
            )
    if not use_mask:
        mask = None
    # A scene with no pixel to score gave a row of dashes (NaN) and exit status 0.
    known = np.isfinite(gt)
    if not known.any():
        raise ValueError(f"scene {scene.name}: the ground truth has no finite value")
    if mask is not None and not (known & mask).any():
        raise ValueError(
            f"scene {scene.name}: {scene.mask_path}: the mask "
            + (
                "leaves out the only pixel with ground truth (--no-mask scores it)"
                if known.sum() == 1
                else f"selects none of the {int(known.sum())} pixels with ground truth "
                "(--no-mask scores them all)"
            )
        )
    return left, right, gt, mask, num_disparities


def _evaluate_scene(
    scene: Scene,
    variants: Sequence[Variant],
    factories: dict[str, Callable[[Variant, int], Matcher]],
    *,
    repeat: int,
    num_disparities: int | None,
    use_mask: bool,
    best_by: str,
    progress: Callable[[str], None] | None,
    notes: list[str] | None = None,
) -> list[Row]:
    """The rows of ``variants`` on ``scene``, in their order, each method's best row after
    its own. An OpenCV matcher that refuses the scene's images (:class:`_Refused`) gives a
    :class:`NotApplicable` row; any other error ends the run, naming the scene and method.
    A note for each OpenCV result with raw values outside the searched range (scored as
    holes) is appended to ``notes``."""
    left, right, gt, mask, num_disparities = _scene_inputs(
        scene, variants, num_disparities=num_disparities, use_mask=use_mask
    )
    rows: list[Row] = []
    for variant in variants:
        try:
            match = factories[variant.method](variant, num_disparities)
            disparity, times = _timed(match, left, right, repeat)
        except _Refused as exc:
            rows.append(NotApplicable(scene.name, variant, str(exc)))
            if progress is not None:
                progress(f"{scene.name}: {' block '.join(_label(rows[-1]))}: n/a ({exc})")
            continue
        except (ValueError, TypeError) as exc:
            raise type(exc)(f"scene {scene.name}: {variant.method}: {exc}") from exc
        if disparity.dtype.kind != "f" or disparity.shape != gt.shape:
            raise ValueError(
                f"scene {scene.name}: {variant.method} returned {disparity.dtype} "
                f"{disparity.shape}, expected float {gt.shape}"
            )
        if isinstance(match, _OpenCVMatch):
            # Values no matching gives (StereoBM's unwritten output, -31960 .. 32521 on
            # 20 x 12 px, was scored as disparities up to 2000 px; that case is n/a now):
            # holes, and said.
            beyond, span = match.beyond_range()
            count = int(beyond.sum())
            if count:
                disparity = np.where(beyond, np.float32(np.nan), disparity)
                if notes is not None:
                    notes.append(
                        f"{variant.method} (block {variant.block_size}) on scene {scene.name}: "
                        f"OpenCV returned {_count(count, 'pixel')} outside the searched range "
                        f"0 .. {num_disparities - 1} px (raw values {span}, disparity x 16, "
                        "OpenCV's hole being -16): not matches; scored as holes"
                    )
        row = EvalResult(
            scene=scene.name,
            variant=variant,
            num_disparities=num_disparities,
            width=gt.shape[1],
            height=gt.shape[0],
            region="all" if mask is None else "nonocc",
            metrics=evaluate(disparity, gt, mask),
            times_s=times,
        )
        if progress is not None:
            progress(
                f"{scene.name}: {_label(row)[0]} block {_label(row)[1]}: "
                f"bad-2 {100 * row.metrics.bad_2:.2f} %, {1e3 * row.time_s:.1f} ms"
            )
        rows.append(row)
    return _with_best(rows, best_by)


# --------------------------------------------------------------------------------------------
# Tables

_METRIC_COLUMNS: tuple[tuple[str, str, float], ...] = (
    ("density %", "density", 100.0),
    ("bad-0.5 %", "bad_0_5", 100.0),
    ("bad-1 %", "bad_1", 100.0),
    ("bad-2 %", "bad_2", 100.0),
    ("bad-4 %", "bad_4", 100.0),
    ("bad-2(est) %", "bad_2_est", 100.0),
    ("D1 %", "d1", 100.0),
    ("avgerr px", "avgerr", 1.0),
    ("rms px", "rms", 1.0),
)
_COLUMNS = (
    "scene",
    "method",
    "block",
    "ndisp",
    "region",
    *(c[0] for c in _METRIC_COLUMNS),
    "time ms",
    "ns/(px*d)",
)


def _label(row: Row) -> tuple[str, str]:
    bs = row.variant.block_size
    block = "default" if bs is None else str(bs)
    best = isinstance(row, EvalResult) and row.best
    return row.variant.method, f"best={block}" if best else block


def _num(value: float, digits: int = 2) -> str:
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def _scored(rows: Sequence[Row]) -> list[EvalResult]:
    return [r for r in rows if isinstance(r, EvalResult)]


def _group_key(r: Row) -> tuple[str, int | None, bool]:
    best = isinstance(r, EvalResult) and r.best
    return (r.variant.method, None if best else r.variant.block_size, best)


def _means(rows: Sequence[Row]) -> list[dict[str, Any]]:
    """One entry per method variant (and per method's best rows), in first-seen order, with
    ``scenes`` the number of scenes it was scored on and ``scenes_not_applicable`` the names
    of those it did not run on (:class:`NotApplicable`): its means are over the others only.
    A variant scored on no scene has NaN means."""
    groups: dict[tuple[str, int | None, bool], list[EvalResult]] = {}
    skipped: dict[tuple[str, int | None, bool], list[str]] = {}
    for r in rows:
        groups.setdefault(_group_key(r), [])
        if isinstance(r, EvalResult):
            groups[_group_key(r)].append(r)
    for r in rows:
        if isinstance(r, NotApplicable):
            best_key = (r.variant.method, None, True)
            for key in (_group_key(r), best_key):  # the best row too, when the method has one
                if key in groups and r.scene not in skipped.setdefault(key, []):
                    skipped[key].append(r.scene)
    out = []
    for (method, bs, best), group in groups.items():
        metrics = {
            k: statistics.fmean(float(getattr(r.metrics, k)) for r in group) if group else math.nan
            for k in DisparityMetrics.__dataclass_fields__
            if k not in ("evaluated", "estimated")
        }
        total_time = sum(r.time_s for r in group)
        out.append(
            {
                "method": method,
                "block_size": bs,
                "best": best,
                "scenes": len(group),
                "scenes_not_applicable": skipped.get((method, bs, best), []),
                "metrics": metrics,
                "time_s": total_time / len(group) if group else math.nan,
                "ns_per_px_disparity": (
                    total_time * 1e9 / sum(r.work for r in group) if group else math.nan
                ),
            }
        )
    return out


def time_ratios(rows: Sequence[Row]) -> list[dict[str, Any]]:
    """Our matchers' time over each peer's, per scene, and their median over the scenes both
    ran: one entry per pair of one of our variants (``stereodepth``, ``sgm``) and a peer's
    (every other method: OpenCV's). :class:`NotApplicable` rows are left out."""
    rows = _scored(rows)
    mine_methods = ("stereodepth", "sgm")
    ours = [r for r in rows if r.variant.method in mine_methods and not r.best]
    others = [r for r in rows if r.variant.method not in mine_methods and not r.best]
    out = []
    for mine in dict.fromkeys(r.variant for r in ours):
        mine_by_scene = {r.scene: r for r in ours if r.variant == mine}
        for theirs in dict.fromkeys(r.variant for r in others):
            per_scene = {
                r.scene: mine_by_scene[r.scene].time_s / r.time_s
                for r in others
                if r.variant == theirs and r.scene in mine_by_scene and r.time_s > 0
            }
            if per_scene:
                out.append(
                    {
                        "method": mine.method,
                        "block_size": mine.block_size,
                        "versus": theirs.method,
                        "versus_block_size": theirs.block_size,
                        "scenes": len(per_scene),
                        "per_scene": per_scene,
                        "median": float(statistics.median(per_scene.values())),
                    }
                )
    return out


def format_time_ratios(rows: Sequence[Row]) -> str:
    """One line per :func:`time_ratios` entry."""

    def name(method: str, block: int | None) -> str:
        return method if block is None else f"{method} (block {block})"

    return "\n".join(
        f"time of {name(t['method'], t['block_size'])} / "
        f"{name(t['versus'], t['versus_block_size'])}, median over {t['scenes']} scene(s): "
        f"{t['median']:.3f}"
        for t in time_ratios(rows)
    )


def _table_rows(rows: Sequence[Row]) -> list[list[str]]:
    cells = []
    none = ["n/a"] * (len(_COLUMNS) - 5)  # a variant not run: no scores, no time
    for r in rows:
        method, block = _label(r)
        if isinstance(r, NotApplicable):
            cells.append([r.scene, method, block, "", "", *none])
            continue
        m = r.metrics
        cells.append(
            [
                r.scene,
                method,
                block,
                str(r.num_disparities),
                r.region,
                *(_num(getattr(m, attr) * k) for _, attr, k in _METRIC_COLUMNS),
                _num(1e3 * r.time_s, 1),
                _num(r.ns_per_px_disparity, 3),
            ]
        )
    total = len(dict.fromkeys(r.scene for r in rows))
    for mean in _means(rows):
        bs = mean["block_size"]
        block = "best" if mean["best"] else ("default" if bs is None else str(bs))
        if not mean["scenes"]:  # not run on any scene
            cells.append([f"mean 0/{total}", mean["method"], block, "", "", *none])
            continue
        cells.append(
            [
                "mean" if mean["scenes"] == total else f"mean {mean['scenes']}/{total}",
                mean["method"],
                block,
                "",
                "",
                *(_num(mean["metrics"][attr] * k) for _, attr, k in _METRIC_COLUMNS),
                _num(1e3 * mean["time_s"], 1),
                _num(mean["ns_per_px_disparity"], 3),
            ]
        )
    return cells


def _shorten(names: Sequence[str], most: int = 5) -> str:
    shown = ", ".join(names[:most])
    return shown if len(names) <= most else f"{shown} and {len(names) - most} more"


def _block_sizes(rows: Sequence[Row]) -> dict[str, set[int | None]]:
    """The block sizes each method of ``rows`` was run at (or not run at: n/a)."""
    sizes: dict[str, set[int | None]] = {}
    for r in rows:
        if not (isinstance(r, EvalResult) and r.best):
            sizes.setdefault(r.variant.method, set()).add(r.variant.block_size)
    return sizes


def _variant_names(rows: Sequence[Row]) -> Callable[[str, int | None, bool], str]:
    """How the lines under the table name a variant of ``rows``: ``opencv-bm:15`` (as
    ``--method`` spells it) for a method run at several block sizes, ``opencv-bm:best`` for
    its best= rows, the method alone for one run at one block size."""
    sizes = _block_sizes(rows)

    def name(method: str, block_size: int | None, best: bool) -> str:
        if best:
            return f"{method}:best"
        if len(sizes.get(method, ())) > 1:
            return f"{method}:{block_size}"
        return method

    return name


def format_not_applicable(rows: Sequence[Row]) -> str:
    """The lines that explain the table's ``n/a`` rows (the variants not run, where and why)
    and its ``mean K/N`` rows (means over K of the run's N scenes); "" when every variant
    was scored on every scene. A variant of a method run at several block sizes is named
    with its block size (``opencv-bm:15``), unless all of them are in the same line."""
    name = _variant_names(rows)
    scenes_of: dict[tuple[str, Variant], list[str]] = {}  # (reason, variant) -> scenes
    for r in rows:
        if isinstance(r, NotApplicable):
            scenes = scenes_of.setdefault((r.reason, r.variant), [])
            if r.scene not in scenes:
                scenes.append(r.scene)
    grouped: dict[tuple[str, tuple[str, ...]], list[Variant]] = {}  # variants alike, together
    for (reason, variant), where in scenes_of.items():
        grouped.setdefault((reason, tuple(where)), []).append(variant)
    sizes = _block_sizes(rows)
    lines = []
    for (reason, on), variants in grouped.items():
        names: dict[str, None] = {}
        for v in variants:
            whole = {x.block_size for x in variants if x.method == v.method} == sizes[v.method]
            names[v.method if whole else name(v.method, v.block_size, False)] = None
        lines.append(f"n/a: {', '.join(names)} not run on {_shorten(on)}: {reason}")
    total = len(dict.fromkeys(r.scene for r in rows))
    covered: dict[int, dict[str, None]] = {}  # scenes -> variants
    for mean in _means(rows):
        if mean["scenes"] < total:
            label = name(mean["method"], mean["block_size"], mean["best"])
            covered.setdefault(mean["scenes"], {})[label] = None
    for count, labels in covered.items():
        names_ = ", ".join(labels)
        none = f"ran on none of the {total} scenes" if total > 1 else "did not run on the scene"
        lines.append(
            f"mean 0/{total}: {names_} {none}: no means"
            if count == 0
            else f"mean {count}/{total}: the means of {names_} are over the {count} of the "
            f"{total} scenes {'it' if len(labels) == 1 else 'each'} ran on: not comparable "
            "with means over all of them"
        )
    return "\n".join(lines)


def format_table(rows: Sequence[Row], *, markdown: bool = False) -> str:
    """The per-scene table with a ``mean`` row per method variant, as text or Markdown.

    A :class:`NotApplicable` in ``rows`` is a row of ``n/a``; the mean row of a variant
    scored on fewer scenes than ``rows`` name reads ``mean K/N`` (K of the N scenes), and
    :func:`format_not_applicable` gives the lines that say why."""
    cells = _table_rows(rows)
    numeric = [i == 3 or i >= 5 for i in range(len(_COLUMNS))]  # not scene, method, block, region
    if markdown:
        lines = ["| " + " | ".join(_COLUMNS) + " |"]
        lines.append("|" + "|".join("---:" if n else "---" for n in numeric) + "|")
        lines += ["| " + " | ".join(c) + " |" for c in cells]
        return "\n".join(lines)
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(_COLUMNS)]

    def line(values: Sequence[str]) -> str:
        return "  ".join(
            v.rjust(w) if n else v.ljust(w) for v, w, n in zip(values, widths, numeric, strict=True)
        ).rstrip()

    out = [line(_COLUMNS), "  ".join("-" * w for w in widths)]
    for i, c in enumerate(cells):
        if i == len(rows) and i > 0:  # the mean rows follow the scenes' after a blank line
            out.append("")
        out.append(line(c))
    return "\n".join(out)


# --------------------------------------------------------------------------------------------
# Command line


#: Other names of eval's methods: ``bm``, as ``stereodepth match`` and ``batch`` call block
#: matching, is eval's ``stereodepth``.
METHOD_ALIASES = {"bm": "stereodepth"}


def _method_spec(text: str) -> tuple[str, tuple[int, ...] | None]:
    name, _, sizes = text.partition(":")
    name = METHOD_ALIASES.get(name, name)
    if name not in METHODS:
        raise argparse.ArgumentTypeError(
            f"method must be one of {', '.join(METHODS)} (optionally METHOD:SIZE[,SIZE...]), "
            f"got {text!r}"
        )
    if not _:
        return name, None
    try:
        values = tuple(int(v) for v in sizes.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"block sizes after {name}: must be integers separated by commas, got {sizes!r}"
        ) from None
    return name, values


def register(subparsers: Any) -> None:
    """Adds ``stereodepth eval`` to the command's subparsers."""
    p = subparsers.add_parser(
        "eval",
        help="run stereo matchers on scenes with ground truth: accuracy and speed",
        description=(
            "Runs stereo matchers on every scene folder in DIR and prints one row per scene "
            "and method: density, bad-pixel rates (holes count as bad), mean and RMS error, "
            "the median run time and the nanoseconds per pixel x disparity, with a mean row "
            "per method. Scene folders hold left.png, right.png, disp_gt.npy "
            "[, mask_nonocc.npy, meta.json] or Middlebury's im0.png, im1.png, disp0GT.pfm / "
            "disp0.pfm [, mask0nocc.png, calib.txt]. Every method searches disparities "
            "0 .. N-1 with N = 16*ceil((D+1)/16), D the largest ground-truth disparity "
            "(meta.json max_disp, else calib.txt ndisp-1, else the ground truth's maximum)."
        ),
    )
    p.add_argument(
        "dir", type=path_arg, metavar="DIR", help="a folder of scene folders (or one scene folder)"
    )
    m = p.add_argument_group("methods")
    m.add_argument(
        "--method",
        nargs="+",
        type=_method_spec,
        default=None,
        metavar="METHOD[:SIZES]",
        help="stereodepth or bm (block matching), sgm (semi-global matching), opencv-bm, "
        "opencv-sgbm, "
        "opencv-sgbm-3way, opencv-sgbm-hh, opencv-sgbm-3way-padded (3WAY on the pair padded on "
        "the left by N columns), each optionally with its own block sizes "
        "(opencv-bm:9,15); default: stereodepth. OpenCV methods are skipped with a note when "
        "cv2 does not import, and are n/a on scenes whose images are not 8-bit or that OpenCV "
        "refuses (too small, say; the others are scored; means over fewer scenes read mean "
        "K/N)",
    )
    m.add_argument(
        "--block-size",
        nargs="+",
        type=int,
        metavar="N",
        help="block sizes for the methods given without their own (defaults: the matcher's "
        "own for stereodepth, 9 for opencv-bm, 5 for opencv-sgbm). With several, each is run "
        "and a best= row per scene picks the one with the lowest --best-by score",
    )
    m.add_argument(
        "--best-by",
        choices=_BEST_BY,
        default="bad_2",
        help="the score that picks the best block size (default bad_2)",
    )
    m.add_argument(
        "--option",
        action=_KeyValueText,
        type=_key_value_text,
        default=[],
        metavar="KEY=VALUE",
        help="keyword argument for stereodepth.block_match, repeatable (e.g. cost=census, "
        "subpixel=false); true/false/none, integers and floats are converted",
    )
    m.add_argument(
        "--sgm-option",
        action=_KeyValueText,
        type=_key_value_text,
        default=[],
        metavar="KEY=VALUE",
        help="keyword argument for stereodepth.semi_global_match (method sgm), repeatable "
        "(e.g. paths=8, p2=300, fill=true)",
    )
    m.add_argument(
        "--opencv-option",
        action=_KeyValueText,
        type=_key_value_text,
        default=[],
        metavar="KEY=VALUE",
        help="OpenCV matcher parameter, repeatable: uniqueness_ratio=10 calls "
        "setUniquenessRatio(10) on every selected OpenCV matcher that has it; each value is "
        "checked first against what OpenCV takes (pre_filter_cap 1..63 for BM, ...). Not "
        "mode: the method chooses it (opencv-sgbm MODE_SGBM, opencv-sgbm-hh MODE_HH, "
        "opencv-sgbm-3way MODE_SGBM_3WAY; MODE_HH4 is not offered)",
    )
    m.add_argument(
        "--channel-order",
        choices=("rgb", "bgr"),
        default="rgb",
        help="the order of the channels of colour images as read: rgb (default; PNG files "
        "hold R, G, B) or bgr (files that hold an OpenCV array's B, G, R); every method "
        "converts to grey accordingly",
    )
    m.add_argument(
        "--num-disparities",
        type=int,
        metavar="N",
        help="search 0 .. N-1 on every scene (a multiple of 16) instead of the range "
        "from the ground truth",
    )
    r = p.add_argument_group("run")
    r.add_argument(
        "--scene",
        action="append",
        default=[],
        metavar="PATTERN",
        help="only scene folders whose name matches this shell pattern, repeatable",
    )
    r.add_argument(
        "--threads",
        type=int,
        default=0,
        metavar="N",
        help="threads for every method (default 0: every core this process may "
        f"use, here {check.available_cores()})",
    )
    r.add_argument(
        "--repeat",
        type=int,
        default=3,
        metavar="N",
        help="timed runs after one warm-up; the time is their median (default 3)",
    )
    r.add_argument(
        "--no-mask",
        action="store_true",
        help="score all pixels with ground truth, also where a scene has a non-occluded mask",
    )
    o = p.add_argument_group("output").add_mutually_exclusive_group()
    o.add_argument("--json", action="store_true", help="print one JSON object")
    o.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    p.set_defaults(func=run)


def _key_value_text(text: str) -> tuple[str, Any, str]:
    """argparse type of eval's ``--option``, ``--sgm-option`` and ``--opencv-option``:
    :func:`stereodepth.cli.key_value_option`'s (key, value) and the value as typed."""
    key, value = key_value_option(text)
    return key, value, text.partition("=")[2]


class _KeyValueText(KeyValueOnce):
    """:class:`stereodepth.cli.KeyValueOnce` that also keeps each value as the user typed it,
    in ``<dest>_text`` (a dict, key to text): eval's messages show that text (``p1=true``
    read ``p1=True``, ``p1=10,p2=5`` read ``p1=(10, 'p2=5')``)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        key, value, text = values
        super().__call__(parser, namespace, (key, value), option_string)
        texts = dict(getattr(namespace, f"{self.dest}_text", None) or {})
        texts[key] = text
        setattr(namespace, f"{self.dest}_text", texts)


def _as_typed(key: str, value: Any, texts: dict[str, str] | None = None) -> str:
    """``KEY=VALUE`` as the user typed it: the text kept by :class:`_KeyValueText`, else the
    value written back as ``--option`` reads it (true, none, 0,4095)."""
    if texts is not None and key in texts:
        return f"{key}={texts[key]}"

    def one(v: Any) -> str:
        return str(v).lower() if v is None or isinstance(v, bool) else str(v)

    shown = ",".join(map(one, value)) if isinstance(value, tuple) else one(value)
    return f"{key}={shown}"


def _variants(
    specs: Sequence[tuple[str, tuple[int, ...] | None]], block_sizes: Sequence[int] | None
) -> list[Variant]:
    """The method variants to run, grouped by method in the order the methods first appear."""
    out: list[Variant] = []
    for name, sizes in specs:
        chosen: Sequence[int | None]
        if sizes is not None:
            chosen = sizes
        elif block_sizes:
            chosen = block_sizes
        else:
            chosen = [METHODS[name]]
        for bs in chosen:
            v = Variant(name, bs)
            _check_block_size(v)
            if v not in out:
                out.append(v)
    order = list(dict.fromkeys(v.method for v in out))
    return sorted(out, key=lambda v: order.index(v.method))


def _matcher_default_block_size() -> int:
    """The default ``block_size`` of stereodepth.block_match, read from its signature."""
    import inspect

    from stereodepth.matching import block_match

    default = inspect.signature(block_match).parameters["block_size"].default
    assert isinstance(default, int)
    return default


def _check_matcher_options(
    options: dict[str, Any], method: str = "stereodepth", texts: dict[str, str] | None = None
) -> None:
    """Checks ``--option`` (``--sgm-option`` for method ``"sgm"``) against the matcher before
    any scene is read: an unknown name, or a value the matcher refuses, is a usage error
    naming the option as typed."""
    import inspect

    from stereodepth import matching, semi_global

    if not options:
        return
    flag = "--option" if method == "stereodepth" else "--sgm-option"
    cls = matching.StereoMatcher if method == "stereodepth" else semi_global.SemiGlobalMatcher
    one_shot = matching.block_match if method == "stereodepth" else semi_global.semi_global_match
    known: list[str] = []
    for func in (one_shot, cls.__init__):
        for name, param in inspect.signature(func).parameters.items():
            if (
                param.kind is inspect.Parameter.KEYWORD_ONLY
                and name not in _RESERVED_OPTIONS
                and name not in known
            ):
                known.append(name)
    for key in options:
        if key not in known:
            raise _usage_error(
                f"{flag} {key}: {method}'s matcher has no option {key!r}; "
                f"it takes {', '.join(known)}"
            )
    try:
        cls(num_disparities=16, **options)
    except (TypeError, ValueError) as exc:
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        culprit = next((k for k in options if message.startswith(k)), None)

        def as_typed(key: str) -> str:
            return _as_typed(key, options[key], texts)

        typed = as_typed(culprit) if culprit is not None else " ".join(map(as_typed, options))
        raise _usage_error(f"{flag} {typed}: {message}") from None


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_jsonable(v) for v in value]
    return value


def _not_applicable_notes(
    skipped: Sequence[NotApplicable], total: int, *, per_variant: bool = False
) -> list[str]:
    """One stderr note per reason: the methods not run, on how many scenes and which. With
    ``per_variant`` (OpenCV's refusals, which may leave out one block size of a method and
    not another), one per reason and variant, named with its block size."""
    by_reason: dict[tuple[str, str], dict[str, None]] = {}
    scenes: dict[tuple[str, str], dict[str, None]] = {}
    for x in skipped:
        name = x.variant.method
        if per_variant:
            name += f" (block {x.variant.block_size})"
        key = (x.reason, name if per_variant else "")
        by_reason.setdefault(key, {})[name] = None
        scenes.setdefault(key, {})[x.scene] = None
    notes = []
    for (reason, variant), methods in by_reason.items():
        names = list(scenes[(reason, variant)])
        which = ", ".join(methods)
        other = total - len(names)
        # With one scene it read "the means of opencv-bm are over the other 0 scene(s)".
        means = (
            f"{which} {'has' if len(methods) == 1 else 'have'} no means"
            if other == 0
            else f"the means of {which} are over the other {_count(other, 'scene')}"
        )
        notes.append(
            f"{which} not run on {len(names)} of {total} scene(s) "
            f"({_shorten(names)}): {reason}; those rows are n/a, and {means}"
        )
    return notes


def _nothing_to_evaluate(skipped: Sequence[NotApplicable], total: int) -> str:
    """The error when no method can run on any scene (every one OpenCV's, every scene 16-bit)."""
    methods = ", ".join(dict.fromkeys(x.variant.method for x in skipped))
    names = _shorten(list(dict.fromkeys(x.scene for x in skipped)))
    where = f"scene {names}" if total == 1 else f"any of the {total} scenes ({names})"
    return (
        f"nothing to evaluate: {methods} cannot run on {where}: {skipped[0].reason} "
        "(stereodepth and sgm take 16-bit images: --method stereodepth sgm)"
    )


def _nothing_scored(refused: Sequence[NotApplicable], total: int) -> str:
    """The error when nothing was scored: OpenCV refused the scenes (``refused``) its
    matchers were run on, and every other row is n/a."""
    first = refused[0]
    more = len(refused) - 1
    where = "the scene" if total == 1 else f"any of the {total} scenes"
    return (
        f"nothing was scored: no method ran on {where}: scene "
        f"{first.scene}: {first.variant.method} (block {first.variant.block_size}): "
        f"{first.reason}" + (f" (and {more} more refusal(s))" if more else "")
    )


def run(args: argparse.Namespace) -> int:
    """Runs ``stereodepth eval``; returns the exit status."""
    from ._extras import require

    require("PIL.Image", "reading images")  # before any work: one line with the install hint
    if args.repeat < 1:
        raise ValueError(f"--repeat must be an integer >= 1, got {args.repeat}")
    from .cli import threads_out_of_range

    if why := threads_out_of_range(args.threads):
        raise ValueError(why)
    if args.num_disparities is not None and (
        not 16 <= args.num_disparities <= MAX_NUM_DISPARITIES or args.num_disparities % 16
    ):
        # Beyond our matchers' limit it was their "num_disparities must be ...", or OpenCV's
        # "integer won't fit into a C int", once a scene was read (OpenCV's int16 output
        # holds disparities up to 2047 px only).
        raise ValueError(
            f"--num-disparities must be a positive multiple of 16 and <= {MAX_NUM_DISPARITIES}, "
            f"got {args.num_disparities}"
        )
    threads = args.threads or check.available_cores()
    options = dict(args.option)
    sgm_options = dict(args.sgm_option)
    for flag, given in (("--option", options), ("--sgm-option", sgm_options)):
        for key in given:
            if key in _RESERVED_OPTIONS:
                raise _usage_error(f"{flag} {key}: {_RESERVED_OPTIONS[key]}")
    opencv_options = dict(args.opencv_option)
    for key in opencv_options:
        # Every spelling that reaches setMode (Mode, mode_ ...), not only "mode".
        if _camel(key) == "Mode":
            typed = _as_typed(key, opencv_options[key], getattr(args, "opencv_option_text", None))
            raise _usage_error(f"--opencv-option {typed}: {_OPENCV_MODE_REFUSED}")
    variants = _variants(args.method or [("stereodepth", None)], args.block_size)
    scenes = find_scenes(args.dir, args.scene)

    notes: list[str] = []
    factories: dict[str, Callable[[Variant, int], Matcher]] = {}
    methods = {v.method for v in variants}
    if options and "stereodepth" not in methods:
        raise _usage_error("--option is for stereodepth.block_match: add --method stereodepth")
    if sgm_options and "sgm" not in methods:
        raise _usage_error("--sgm-option is for stereodepth.semi_global_match: add --method sgm")
    _check_matcher_options(options, texts=getattr(args, "option_text", None))
    _check_matcher_options(sgm_options, "sgm", getattr(args, "sgm_option_text", None))
    cv2: Any = None
    if methods & set(_OPENCV_METHODS):
        try:
            import cv2
        except ImportError:
            skipped = ", ".join(sorted(methods & set(_OPENCV_METHODS)))
            how = '(pip install opencv-python-headless, or "stereodepth[bench]")'
            variants = [v for v in variants if v.method not in _OPENCV_METHODS]
            if not variants:  # a missing extra: ImportError, exit status 1
                why = f"{skipped} need(s) OpenCV, which is not installed {how}"
                raise ImportError(why) from None
            notes.append(f"skipped {skipped}: OpenCV is not installed {how}")
        else:
            for key in opencv_options:
                if key in ("num_disparities", "min_disparity", "block_size"):
                    raise _usage_error(f"--opencv-option {key}: {_RESERVED_OPTIONS[key]}")
                probes = [
                    cv2.StereoBM_create() if m == "opencv-bm" else cv2.StereoSGBM_create()
                    for m in methods & set(_OPENCV_METHODS)
                ]
                if not any(hasattr(x, "set" + _camel(key)) for x in probes):
                    raise _usage_error(
                        f"--opencv-option {key}: no selected OpenCV matcher has set{_camel(key)}()"
                    )
            opencv_texts = getattr(args, "opencv_option_text", None)
            _check_opencv_options(
                opencv_options, [v for v in variants if v.method in _OPENCV_METHODS], opencv_texts
            )
            factory = _opencv_factory(cv2, opencv_options, args.channel_order, opencv_texts)
            for name in _OPENCV_METHODS:
                factories[name] = factory
    elif opencv_options:
        raise _usage_error("--opencv-option needs an OpenCV method (--method opencv-bm ...)")
    for name in ("stereodepth", "sgm"):
        if name in methods:
            factories[name] = _stereodepth_factory(
                threads, options, args.channel_order, sgm_options
            )
    for note in notes:
        print(f"stereodepth eval: {note}", file=sys.stderr)

    if "stereodepth" in factories:
        # Name the matcher's default block size in the results (passing it changes nothing).
        default_bs = _matcher_default_block_size()
        variants = list(
            dict.fromkeys(
                Variant(v.method, default_bs)
                if v.method == "stereodepth" and v.block_size is None
                else v
                for v in variants
            )
        )

    progress = None
    if not args.json and sys.stderr.isatty():

        def progress(text: str) -> None:
            print(text, file=sys.stderr, flush=True)

    # Every scene checked before any is matched: a fault in the last one (a mask selecting
    # nothing, a range its ground truth leaves) ended the run after the others' work, and
    # their results were lost with it. A scene an OpenCV method cannot take (16-bit images)
    # is no fault: that method's rows there are n/a, and the others' are scored.
    not_run: dict[str, list[NotApplicable]] = {}
    for scene in scenes:
        left, *_ = _scene_inputs(
            scene, variants, num_disparities=args.num_disparities, use_mask=not args.no_mask
        )
        # intensity_range is for 16-bit images: our matchers refused it on an 8-bit scene
        # when its turn came, after the work on the scenes before it, all of it lost.
        for flag, given, method in (
            ("--option", options, "stereodepth"),
            ("--sgm-option", sgm_options, "sgm"),
        ):
            if given.get("intensity_range") is not None and left.dtype == np.uint8:
                texts = getattr(args, f"{flag[2:].replace('-', '_')}_text", None)
                raise _usage_error(
                    f"{flag} {_as_typed('intensity_range', given['intensity_range'], texts)}: "
                    f"intensity_range is for 16-bit images ({method} matches 8-bit ones as "
                    f"they are), and scene {scene.name} is 8-bit: leave the option out, or "
                    "that scene (--scene)"
                )
        not_run[scene.name] = _not_applicable(scene.name, variants, left)
    not_applicable = [x for xs in not_run.values() for x in xs]
    if len(not_applicable) == len(scenes) * len(variants):
        raise ValueError(_nothing_to_evaluate(not_applicable, len(scenes)))
    for note in _not_applicable_notes(not_applicable, len(scenes)):
        notes.append(note)
        print(f"stereodepth eval: {note}", file=sys.stderr)

    rows: list[Row] = []
    warnings: list[str] = []  # OpenCV's values beyond the searched range
    saved_threads = cv2.getNumThreads() if cv2 is not None else None
    try:
        if cv2 is not None:
            cv2.setNumThreads(threads)
        for scene in scenes:
            missing = {x.variant: x for x in not_run[scene.name]}
            scored = (
                _evaluate_scene(
                    scene,
                    [v for v in variants if v not in missing],
                    factories,
                    repeat=args.repeat,
                    num_disparities=args.num_disparities,
                    use_mask=not args.no_mask,
                    best_by=args.best_by,
                    progress=progress,
                    notes=warnings,
                )
                if len(missing) < len(variants)
                else []
            )
            for method in dict.fromkeys(v.method for v in variants):  # in the variants' order
                rows += [r for r in scored if r.variant.method == method]
                rows += [missing[v] for v in variants if v.method == method and v in missing]
    finally:
        if cv2 is not None and saved_threads is not None:
            cv2.setNumThreads(saved_threads)
    # The scenes an OpenCV matcher refused (images too small for its block size and range):
    # n/a rows, as on 16-bit scenes; they ended the whole run.
    refused = [r for r in rows if isinstance(r, NotApplicable) and r not in not_applicable]
    if refused and not _scored(rows):
        raise ValueError(_nothing_scored(refused, len(scenes)))
    for note in _not_applicable_notes(refused, len(scenes), per_variant=True) + warnings:
        notes.append(note)
        print(f"stereodepth eval: {note}", file=sys.stderr)

    if args.json:
        from . import __version__

        report = {
            "dir": str(args.dir),
            "threads": threads,
            "repeat": args.repeat,
            "best_by": args.best_by,
            "channel_order": args.channel_order,
            # The matcher options as given (after conversion), so a report says what it scored.
            "options": options,
            "sgm_options": sgm_options,
            "opencv_options": opencv_options,
            "stereodepth_version": __version__,
            "opencv_version": None if cv2 is None else str(cv2.__version__),
            "notes": notes,
            "scenes": [scene.name for scene in scenes],
            "results": [r.as_dict() for r in _scored(rows)],
            "not_applicable": [r.as_dict() for r in rows if isinstance(r, NotApplicable)],
            "means": _means(rows),
            "time_ratios": time_ratios(rows),
        }
        print(json.dumps(_jsonable(report), indent=2, allow_nan=False))
        return 0
    ratios = format_time_ratios(rows)
    why = format_not_applicable(rows)
    if args.markdown:
        print(format_table(rows, markdown=True))
        if why:
            print()
            print(why.replace("\n", "  \n"))
        if ratios:
            print()
            print(ratios.replace("\n", "  \n"))  # Markdown line breaks
        return 0
    print(
        f"{len(scenes)} scene(s) in {args.dir}; threads {threads}; time: median of "
        f"{args.repeat} run(s) after a warm-up; scores over non-occluded pixels where a "
        "scene has a mask (region nonocc)"
    )
    print()
    print(format_table(rows))
    if why:
        print()
        print(why)
    if ratios:
        print()
        print(ratios)
    return 0
