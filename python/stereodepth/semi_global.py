"""Dense disparity by semi-global matching, natively: :func:`semi_global_match` and
:class:`SemiGlobalMatcher`.

Semi-global matching (Hirschmüller, "Accurate and efficient stereo processing by semi-global
matching and mutual information", CVPR 2005; "Stereo processing by semiglobal matching and
mutual information", IEEE PAMI 30(2), 2008) adds to each pixel's matching costs the least
costs of paths that reach it from several directions, with a small penalty ``p1`` for a change
of one disparity between neighbours along a path and a larger one ``p2`` for a jump, so that
the winner agrees with its neighbours unless the image says otherwise. It shares every other
step with the block matcher (:mod:`stereodepth.matching`); the native kernel and the numpy
oracle (:func:`stereodepth.reference.semi_global_match`) follow the same integer steps and
agree exactly on the integer disparities and the validity, and within 1e-3 px after the
sub-pixel step.

Steps, in the kernel and in the oracle alike:

1. Grey, as the block matcher (RGB by OpenCV's fixed-point ``COLOR_RGB2GRAY``).
2. Pixel cost: the Hamming distance of the census codes over the border of the 5x5 window
   (Zabih & Woodfill, "Non-parametric local transforms for computing visual correspondence",
   ECCV 1994; the block matcher's 16-bit ring), 0..16, the right pixel at column
   ``clamp(x - d)``; then summed over a ``block_size`` x ``block_size`` box (1 or 3; edge
   rows and columns repeat), so the cost ``C(p, d)`` is in ``0 .. 16 * block_size**2``.
3. The border band (``border="clip"``, the default): a candidate ``d`` whose right pixel
   ``x - d`` lies outside the right image costs the most a cost can be
   (``16 * block_size**2``) and never wins; a pixel is matched over the candidates that lie
   inside the image, and is NaN when none does or when every one inside lies within one
   disparity of the winner (step 5: no second-best sum to tell it from; the first two or
   three columns). ``border="opencv"`` makes every pixel whose full search range leaves
   the right image NaN, as OpenCV does (the leftmost ``min_disparity + num_disparities - 1``
   columns).
4. Paths: for each direction r (``paths=4``: from the left, the right, above and below;
   ``paths=8`` adds the four diagonals; ``paths=3``, one pass over the image: from the left,
   the right and above, the path from above starting again at the first row of each stripe,
   so that the stripes can be matched in parallel: the ``H`` rows make
   ``n = ceil(H / 64)`` stripes, one more when that is odd and above 1 (an even count
   shares evenly between two cores), stripe ``s`` being rows ``floor(s * H / n)`` to
   ``floor((s + 1) * H / n) - 1``; :func:`stripe_starts`), in scan order,
   ``L_r(p, d) = C(p, d) + min(L_r(q, d), L_r(q, d - 1) + P1, L_r(q, d + 1) + P1,
   m + P2') - m`` where ``q = p - r`` is the previous pixel on the path and ``m`` the least
   ``L_r(q, .)``; at the first pixel of a path ``L_r(p, d) = C(p, d)``. ``P2'`` adapts to the
   intensity step between the two pixels, ``s = |I(p) - I(q)|`` in grey levels (uint16:
   shifted right by 8): ``P2' = max(P1, (P2 * k) // (k + s))`` with ``k = p2_step`` (the step
   that halves P2; 0 turns the adaptation off, ``P2' = P2``). The subtraction of ``m`` keeps
   ``L_r <= C_max + P2``, so each path fits 16 bits (``C_max + P2 < 2**14``, checked) and
   their sum ``S(p, d) = sum_r L_r(p, d)`` fits in 16 bits when
   ``paths * (16 * block_size**2 + p2) <= 65535`` (checked). The costs and paths run over
   ``num_disparities`` rounded up to a multiple of 16 (:func:`run_disparities`:
   the lanes of the SIMD kernels' vectors, so that any ``num_disparities`` runs at their
   speed); the candidates above ``num_disparities`` take part in the paths (in ``m`` and as
   neighbours ``d + 1``) but, as candidates outside the image, never win and are no
   neighbours of the sub-pixel fit; steps 5 on see ``num_disparities`` candidates.
5. Winner, uniqueness, left-right check, sub-pixel fit and confidence on ``S`` by the block
   matcher's rules (:mod:`stereodepth.matching`, steps 4-6), over the candidates inside the
   image: the least sum, the lowest disparity on a tie; every sum more than one disparity
   away must exceed the winner's by more than ``uniqueness_ratio`` percent; the right image's
   own winner at ``x - d`` (least ``S`` along the other diagonal) within ``lr_max_diff``;
   the fit (``"equiangular"`` by default: the V-shaped fit, which suits census costs; or
   ``"parabola"``) moves the winner only when both neighbours ``d - 1`` and ``d + 1`` are
   candidates inside the image.
6. Median (``median=True``): each valid pixel becomes the lower median of the valid pixels in
   its 3x3 window (inside the image); invalid pixels stay NaN.
7. Speckle filter, as the block matcher's.
8. Fill (``fill=True``; off by default): each pixel still NaN takes the smaller of the nearest
   valid disparities to its left and to its right on its row (the background, the way
   Hirschmüller 2008 interpolates occlusions), or the one that exists; a row without any
   valid pixel stays NaN. Its confidence stays 0. This step runs in numpy after the kernel
   (:func:`fill_background`).

Memory, beside the images and the outputs: ``paths=3`` keeps nothing image-sized, only a few
rows of ``W * num_disparities`` per thread (O(W D): 3.9 MiB per thread at W = 1920, D = 256
with the AVX2 and AVX-512 kernels, 7.5 MiB with the baseline build); each thread computes the
grey and census rows it needs, and the median runs in place in the output. ``paths`` 4 and 8
keep the sums ``S`` (2 bytes per pixel and disparity), the costs (1 byte per pixel and
disparity) and the census and grey images (7 bytes per pixel), plus a few rows per thread.
The disparities counted are ``num_disparities`` rounded up to a multiple of 16 (step 4).
:func:`memory_estimate` gives the figure, and the matcher refuses with ValueError above
``max_memory_mb``.

Threads: the horizontal paths and the final steps split the rows, the vertical and diagonal
paths split the columns (threads meet at every row for the diagonals); on two threads,
``paths`` 4 and 8 instead run the downward and the upward pass at once, one thread each, which
wait for each other once, at the middle row, and finish the rows each completes; ``paths=3``
splits the stripes. The output does not depend on the number of threads.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _core
from . import _validate as check
from .matching import FixedParameters, MatcherOptions, check_flag, run_native

__all__ = [
    "SemiGlobalMatcher",
    "fill_background",
    "memory_estimate",
    "semi_global_match",
]

#: Census bits per pixel (the border of the 5x5 window).
CENSUS_BITS = 16
#: The box sizes of the pixel cost (costs are stored in 8 bits: 16 * 3**2 = 144).
BLOCK_SIZES = (1, 3)
PATH_COUNTS = (3, 4, 8)
#: paths=3 (one pass): the most rows of a stripe, whose path from above starts at its first row.
STRIPE_ROWS = 64


def run_disparities(num_disparities: int) -> int:
    """The disparities whose costs and paths are computed: ``num_disparities`` rounded up to a
    multiple of 16 (the lanes of the SIMD kernels' vectors), of which only the first
    ``num_disparities`` may win (step 4 of this module's description). Raises TypeError or
    ValueError for a ``num_disparities`` that is not an integer >= 1."""
    nd = check.integer("num_disparities", num_disparities, minimum=1)
    return -(-nd // 16) * 16


def stripe_starts(rows: int) -> list[int]:
    """The first row of each stripe of ``paths=3`` (the rows where its path from above starts
    again), for an image of ``rows`` rows: ``n = ceil(rows / 64)`` stripes, one more when
    ``n`` is odd and above 1, of nearly equal height (``floor(s * rows / n)`` for stripe
    ``s``), so that two threads get the same number of rows. ``[0]`` for ``rows <= 64``.
    Raises TypeError or ValueError for a ``rows`` that is not an integer >= 1."""
    rows = check.integer("rows", rows, minimum=1)
    n = max(1, -(-rows // STRIPE_ROWS))
    if n > 1 and n % 2 == 1:
        n += 1
    return [s * rows // n for s in range(n)]


# Defaults, chosen by measuring on the shared scenes among round values, each change checked
# on both halves of the scenes and the choice by leave-one-out (bench/README.md, "Semi-global
# matching"). The rules behind them:
# - P1 about a quarter of the box cost's range (0..144), P2 a bit under twice that range,
#   halved at an intensity step of 32 grey levels (so P2' = 8000 / (32 + step), never below
#   P1);
# - the fit that suits the cost: census costs grow linearly with the shift, so the V-shaped
#   (equiangular) fit (Shimizu & Okutomi, ICCV 2001), as the block matcher's census default;
# - filters kept by their precision (the share of the pixels they remove that are wrong; holes
#   count as bad, so every removal of a right pixel costs): the speckle filter (about 9 in 10)
#   does the cleaning, at OpenCV's usual 100 px / 2 px; the left-right check rejects
#   disagreements of more than 4 px (a looser check passes the occluded band at the left
#   border); the uniqueness check (barely more than half of its rejects wrong) is off.
DEFAULT_BLOCK_SIZE = 3
DEFAULT_P1 = 40
DEFAULT_P2 = 250
DEFAULT_P2_STEP = 32
DEFAULT_PATHS = 3
#: The fit that ``subpixel=True`` (the default) chooses.
DEFAULT_SUBPIXEL = "equiangular"
DEFAULT_UNIQUENESS_RATIO = 0.0
DEFAULT_LR_MAX_DIFF = 4.0
DEFAULT_SPECKLE_WINDOW = 100
DEFAULT_SPECKLE_RANGE = 2.0
DEFAULT_MAX_MEMORY_MB = 2048.0


def cost_max(block_size: int) -> int:
    """The largest box cost: 16 census bits times the box's pixels."""
    return CENSUS_BITS * block_size * block_size


class SemiGlobalOptions(MatcherOptions):
    """The checked, resolved parameters shared by the native kernel and the numpy oracle."""

    __slots__ = ("block_size", "fill", "max_memory_mb", "median", "p1", "p2", "p2_step", "paths")

    def __init__(
        self,
        *,
        num_disparities: Any,
        min_disparity: Any = 0,
        block_size: Any = DEFAULT_BLOCK_SIZE,
        p1: Any = DEFAULT_P1,
        p2: Any = DEFAULT_P2,
        p2_step: Any = DEFAULT_P2_STEP,
        paths: Any = DEFAULT_PATHS,
        subpixel: Any = True,
        uniqueness_ratio: Any = DEFAULT_UNIQUENESS_RATIO,
        lr_max_diff: Any = DEFAULT_LR_MAX_DIFF,
        median: Any = True,
        speckle_window: Any = DEFAULT_SPECKLE_WINDOW,
        speckle_range: Any = DEFAULT_SPECKLE_RANGE,
        border: Any = "clip",
        fill: Any = False,
        max_memory_mb: Any = DEFAULT_MAX_MEMORY_MB,
        threads: Any = None,
        return_confidence: Any = False,
        channel_order: Any = "rgb",
        intensity_range: Any = None,
    ) -> None:
        self._check_range(num_disparities, min_disparity)
        bs = check.integer("block_size", block_size)
        if bs not in BLOCK_SIZES:
            raise ValueError(
                f"block_size must be 1 or 3 (box costs are stored in 8 bits), got {bs}"
            )
        self.block_size = bs
        pc = check.integer("paths", paths)
        if pc not in PATH_COUNTS:
            raise ValueError(f"paths must be 3, 4 or 8, got {pc}")
        self.paths = pc
        limit = min(65535 // pc, 16383) - cost_max(bs)
        self.p1 = check.integer("p1", p1, minimum=0)
        if self.p1 > limit:
            raise ValueError(
                f"p1 must be an integer in [0, {limit}] for paths={pc} and block_size={bs} "
                f"(p1 <= p2 <= {limit}), got {self.p1}"
            )
        p2v = check.integer("p2", p2)
        if not self.p1 <= p2v <= limit:
            raise ValueError(
                f"p2 must be an integer in [p1, {limit}] = [{self.p1}, {limit}] for paths={pc} "
                f"and block_size={bs} (a path cost, {cost_max(bs)} + p2, must stay below 2**14 "
                f"and the sum over the paths, paths * ({cost_max(bs)} + p2), fit in 16 bits), "
                f"got {p2v}"
            )
        self.p2 = p2v
        self.p2_step = check.integer("p2_step", p2_step, minimum=0, maximum=65535)
        self._check_decision(
            subpixel=subpixel,
            default_subpixel=DEFAULT_SUBPIXEL,
            uniqueness_ratio=uniqueness_ratio,
            lr_max_diff=lr_max_diff,
            speckle_window=speckle_window,
            speckle_range=speckle_range,
        )
        self.median = check_flag("median", median)
        self.fill = check_flag("fill", fill)
        self.max_memory_mb = check.positive("max_memory_mb", max_memory_mb)
        self._check_io(
            threads=threads,
            return_confidence=return_confidence,
            channel_order=channel_order,
            intensity_range=intensity_range,
            border=border,
        )

    def as_dict(self) -> dict[str, Any]:
        """The public parameters, resolved (``subpixel`` as the fit's name or False)."""
        return {
            "num_disparities": self.num_disparities,
            "min_disparity": self.min_disparity,
            "block_size": self.block_size,
            "p1": self.p1,
            "p2": self.p2,
            "p2_step": self.p2_step,
            "paths": self.paths,
            "subpixel": self.subpixel if self.subpixel is not None else False,
            "uniqueness_ratio": self.uniqueness_ratio,
            "lr_max_diff": self.lr_max_diff,
            "median": self.median,
            "speckle_window": self.speckle_window,
            "speckle_range": self.speckle_range,
            "border": self.border,
            "fill": self.fill,
            "max_memory_mb": self.max_memory_mb,
            "threads": self.threads,
            "return_confidence": self.return_confidence,
            "channel_order": self.channel_order,
            "intensity_range": self.intensity_range,
        }


def fill_background(disparity: np.ndarray) -> np.ndarray:
    """Fills the NaN pixels of a float disparity map in place along each row with the smaller
    of the nearest valid values to the left and to the right (the one that exists at the row's
    ends; rows without a valid pixel stay NaN); returns the map. Step 8 of
    :mod:`stereodepth.semi_global`. Valid means finite: an infinite value is filled as a NaN
    is. ``disparity`` is a writeable (H, W) float16, float32 or float64 numpy array (TypeError
    for another type or dtype, ValueError for another shape or a read-only one)."""
    if not isinstance(disparity, np.ndarray):
        raise TypeError(
            f"disparity must be a numpy.ndarray (filled in place), got {type(disparity).__name__}"
        )
    check.not_masked("disparity", disparity)
    if disparity.dtype.kind != "f":
        raise TypeError(
            f"disparity must be a float array (NaN for holes), got dtype {disparity.dtype}"
        )
    if disparity.ndim != 2:
        raise ValueError(f"disparity must be 2-D (H, W), got shape {disparity.shape}")
    if not disparity.flags.writeable:
        raise ValueError("disparity must be writeable (it is filled in place)")
    h, w = disparity.shape
    valid = np.isfinite(disparity)
    cols = np.broadcast_to(np.arange(w), (h, w))
    left_idx = np.maximum.accumulate(np.where(valid, cols, -1), axis=1)
    right_idx = np.minimum.accumulate(np.where(valid, cols, w)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(h)[:, None]
    inf = np.float32(np.inf)
    left_val = np.where(left_idx >= 0, disparity[rows, np.clip(left_idx, 0, w - 1)], inf)
    right_val = np.where(right_idx < w, disparity[rows, np.clip(right_idx, 0, w - 1)], inf)
    filled = np.minimum(left_val, right_val)
    todo = ~valid & np.isfinite(filled)
    disparity[todo] = filled[todo]
    return disparity


def memory_estimate(
    shape: tuple[int, int],
    *,
    num_disparities: int,
    paths: int = DEFAULT_PATHS,
    threads: int | None = 1,
    isa: str = "auto",
    block_size: int = DEFAULT_BLOCK_SIZE,
) -> int:
    """Bytes the native matcher allocates beside its inputs and outputs for a pair of
    ``shape`` (H, W), with the kernels of ``isa`` (``"auto"``: the ones that run; the
    matcher checks its own instruction set against ``max_memory_mb``).

    ``paths=3``: per thread a few rows of W x ``num_disparities`` (about 8 bytes per column
    and disparity with the AVX2 and AVX-512 kernels, 15 with the baseline build: 3.9 and 7.5
    MiB at W = 1920, D = 256) and the 3x3 median's rows; nothing grows with H. ``paths`` 4
    and 8: 3 bytes per pixel and disparity (16-bit sums, 8-bit costs), 7 per pixel (census
    and grey images) and a few rows per thread. The figure is for an RGB pair with
    ``median=True`` (grey pairs need a little less); the speckle filter's runs, which depend
    on the disparities, are not counted (12 bytes per run of linked pixels in a row). The
    disparities are counted rounded up to a multiple of 16 (:func:`run_disparities`). The
    figure is capped at 1.8e19 bytes (shapes of that size hold more pixels than any memory).

    Raises TypeError or ValueError for a ``shape`` that is not two integers >= 1 and for the
    parameters :func:`semi_global_match` refuses, naming the parameter; ValueError for an
    unknown ``isa`` or one this CPU cannot run."""
    if not isinstance(shape, (tuple, list)):
        raise TypeError(f"shape must be a tuple (H, W), got {type(shape).__name__} {shape!r}")
    if len(shape) != 2:
        raise ValueError(f"shape must be (H, W), two integers, got {shape!r}")
    h, w = (
        check.integer(f"shape[{i}]", v, minimum=1, maximum=check.MAX_NATIVE_INT)
        for i, v in enumerate(shape)
    )
    o = SemiGlobalOptions(
        num_disparities=num_disparities, paths=paths, block_size=block_size, threads=threads
    )
    if not isinstance(isa, str):
        raise TypeError(f"isa must be a str, got {type(isa).__name__} {isa!r}")
    threads_n = o.threads or check.available_cores()  # None or 0: every core, as the matcher
    return int(
        _core.semi_global_memory(h, w, o.num_disparities, o.paths, threads_n, isa, o.block_size)
    )


class SemiGlobalMatcher(FixedParameters):
    """Semi-global matching as an object for per-frame use, the sibling of
    :class:`stereodepth.StereoMatcher`.

    The parameters are those of :func:`semi_global_match`, checked once here;
    :meth:`compute` then matches a pair, reusing the matcher's buffers from one frame to the
    next. Calls from several threads on one matcher are safe (they take turns).

    ``isa`` picks the instruction set of the kernel: ``"auto"`` (the best this CPU runs, capped
    by the environment variable STEREODEPTH_ISA), ``"baseline"``, ``"avx2"`` or ``"avx512"``;
    every choice gives the same output.

    The parameters are fixed: assigning one is an AttributeError (make a new matcher). A
    matcher pickles as its parameters and ``isa``: the copy has buffers of its own.
    """

    __slots__ = ("_isa_arg", "_native", "_options")

    def __init__(
        self,
        *,
        num_disparities: int,
        min_disparity: int = 0,
        block_size: int = DEFAULT_BLOCK_SIZE,
        p1: int = DEFAULT_P1,
        p2: int = DEFAULT_P2,
        p2_step: int = DEFAULT_P2_STEP,
        paths: int = DEFAULT_PATHS,
        subpixel: bool | str = True,
        uniqueness_ratio: float = DEFAULT_UNIQUENESS_RATIO,
        lr_max_diff: float | None = DEFAULT_LR_MAX_DIFF,
        median: bool = True,
        speckle_window: int = DEFAULT_SPECKLE_WINDOW,
        speckle_range: float = DEFAULT_SPECKLE_RANGE,
        border: str = "clip",
        fill: bool = False,
        max_memory_mb: float = DEFAULT_MAX_MEMORY_MB,
        threads: int | None = None,
        return_confidence: bool = False,
        channel_order: str = "rgb",
        intensity_range: tuple[int, int] | None = None,
        isa: str = "auto",
    ) -> None:
        self._options = SemiGlobalOptions(
            num_disparities=num_disparities,
            min_disparity=min_disparity,
            block_size=block_size,
            p1=p1,
            p2=p2,
            p2_step=p2_step,
            paths=paths,
            subpixel=subpixel,
            uniqueness_ratio=uniqueness_ratio,
            lr_max_diff=lr_max_diff,
            median=median,
            speckle_window=speckle_window,
            speckle_range=speckle_range,
            border=border,
            fill=fill,
            max_memory_mb=max_memory_mb,
            threads=threads,
            return_confidence=return_confidence,
            channel_order=channel_order,
            intensity_range=intensity_range,
        )
        if not isinstance(isa, str):
            raise TypeError(f"isa must be a str, got {type(isa).__name__} {isa!r}")
        self._isa_arg = isa
        o = self._options
        self._native = _core.SemiGlobalMatcher(
            o.num_disparities,
            o.min_disparity,
            o.block_size,
            o.p1,
            o.p2,
            o.p2_step,
            o.paths,
            o.subpixel or "none",
            o.uniqueness_ratio,
            -1.0 if o.lr_max_diff is None else o.lr_max_diff,
            o.median,
            o.speckle_window,
            o.speckle_range,
            o.border == "clip",
            o.max_memory_mb,
            o.threads,
            isa,
        )

    @property
    def params(self) -> dict[str, Any]:
        """The resolved parameters."""
        return self._options.as_dict()

    @property
    def isa(self) -> str:
        """The instruction set the kernel runs."""
        return str(self._native.isa)

    def __repr__(self) -> str:
        args = [f"{k}={v!r}" for k, v in self.params.items()]
        if self._isa_arg != "auto":  # a matcher made for one instruction set says which
            args.append(f"isa={self._isa_arg!r}")
        return f"SemiGlobalMatcher({', '.join(args)})"

    def compute(self, left: Any, right: Any) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """The float32 disparity of ``left`` (and the confidence, if the matcher was made
        with ``return_confidence=True``); see :func:`semi_global_match`."""
        finish = fill_background if self._options.fill else None
        return run_native(self._native, self._options, left, right, finish)


def semi_global_match(
    left: Any,
    right: Any,
    *,
    num_disparities: int,
    min_disparity: int = 0,
    block_size: int = DEFAULT_BLOCK_SIZE,
    p1: int = DEFAULT_P1,
    p2: int = DEFAULT_P2,
    p2_step: int = DEFAULT_P2_STEP,
    paths: int = DEFAULT_PATHS,
    subpixel: bool | str = True,
    uniqueness_ratio: float = DEFAULT_UNIQUENESS_RATIO,
    lr_max_diff: float | None = DEFAULT_LR_MAX_DIFF,
    median: bool = True,
    speckle_window: int = DEFAULT_SPECKLE_WINDOW,
    speckle_range: float = DEFAULT_SPECKLE_RANGE,
    border: str = "clip",
    fill: bool = False,
    max_memory_mb: float = DEFAULT_MAX_MEMORY_MB,
    threads: int | None = None,
    return_confidence: bool = False,
    channel_order: str = "rgb",
    intensity_range: tuple[int, int] | None = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Dense disparity of the left image by semi-global matching, natively.

    Parameters
    ----------
    left, right
        The rectified pair, the same shape and dtype: (H, W) uint8 or uint16 grey, or
        (H, W, 3) uint8 RGB (turned into grey as OpenCV's ``COLOR_RGB2GRAY``).
    num_disparities
        How many disparities to search, any integer in [1, 4096].
    min_disparity
        The smallest disparity searched, in pixels; may be negative. A range with no
        disparity in ``-(W - 1) .. W - 1`` for an image W pixels wide (no pixel has a
        candidate inside the right image) is refused with ValueError.
    block_size
        The side of the box the census costs are summed over: 1 or 3.
    p1, p2
        Path penalties (integers, in the units of the box cost, which itself runs over
        0..16 * block_size**2) for a change of one disparity and for a larger jump between
        neighbours; ``0 <= p1 <= p2 <= min(65535 // paths, 16383) - 16 * block_size**2``.
    p2_step
        Grey levels of intensity step between neighbours that halve ``p2``
        (``P2' = max(p1, p2 * p2_step // (p2_step + step))``); 0 keeps ``p2`` everywhere.
    paths
        3 (one pass: along the row and from above, restarting at each stripe of at most 64
        rows; least memory),
        4 (horizontal and vertical) or 8 (and the diagonals).
    subpixel
        ``True`` (the default) or ``"equiangular"``: the V-shaped fit, which suits census
        costs; ``"parabola"``; or ``False`` for integers.
    uniqueness_ratio
        Percent by which every sum more than one disparity away must exceed the winner's;
        0 (the default) turns the check off.
    lr_max_diff
        Largest difference, in pixels, between the left disparity and the right image's own
        at the matched pixel (default 4); None turns the check off.
    median
        A 3x3 median of the valid disparities (invalid pixels stay NaN).
    speckle_window, speckle_range
        Remove connected regions of at most ``speckle_window`` pixels whose neighbouring
        disparities differ by at most ``speckle_range`` px (default 100 px and 2 px); 0 turns
        it off.
    border
        ``"clip"``: pixels near the image's left edge are matched over the disparities whose
        right pixel lies in the image (NaN where those leave the winner no rival more than
        one disparity away); ``"opencv"``: those pixels are NaN, as OpenCV's.
    fill
        Fill the pixels left NaN with the smaller of the nearest valid disparities to their
        left and right on the row (background interpolation; off by default).
    max_memory_mb
        Refuse (ValueError) when the matcher's buffers, beside the images and the outputs,
        would exceed this many MiB (the figure of :func:`memory_estimate`: a few MiB per
        thread for ``paths=3``, about 3 bytes per pixel and disparity for 4 and 8).
    threads
        Threads to use; None or 0 for every core available (the affinity mask, lowered to a
        container's CPU quota: ``stereodepth.build_info()["default_threads"]``). Paths 4 and 8
        use at most that many, whatever is asked (their passes meet at every row). The
        output does not depend on it.
    return_confidence
        Also return the confidence, ``(second - best) / second`` of the path sums (``second``
        the least sum more than one disparity away from the winner; 1 when there is none,
        which happens only with ``num_disparities <= 3``). It measures the margin of the
        aggregated sums, which the paths carry across a textureless region from its
        surroundings and the border: there it can be high though the pixel itself is flat (a
        uniform image gives disparity 0 at confidence 1, as OpenCV's SGBM gives 0).
    channel_order, intensity_range
        As :func:`stereodepth.block_match`: ``"rgb"`` or ``"bgr"`` (``cv2.imread``) for
        (H, W, 3) images; for uint16 pairs the range stretched onto the scale of uint8
        (default: the pair's own joint [min, max]).

    Returns
    -------
    The float32 (H, W) disparity in pixels, NaN where there is no reliable match; with
    ``return_confidence=True``, ``(disparity, confidence)``, the confidence float32 in [0, 1]
    (0 where the disparity is NaN).

    Raises
    ------
    TypeError
        An image or parameter of the wrong type or dtype.
    ValueError
        A parameter out of range, images of different shapes, or an image whose matching
        would need more than ``max_memory_mb`` (the message gives the estimate; lower
        ``num_disparities``, match a smaller image, or raise ``max_memory_mb``).

    The steps and rules are described in :mod:`stereodepth.semi_global`. Sources: H.
    Hirschmüller, CVPR 2005 and IEEE PAMI 30(2) 2008 (semi-global matching); R. Zabih and J.
    Woodfill, ECCV 1994 (census). The GIL is released while the kernel runs; Ctrl-C on the
    main thread stops it within a few rows and raises KeyboardInterrupt, as for
    :func:`stereodepth.block_match`.
    """
    matcher = SemiGlobalMatcher(
        num_disparities=num_disparities,
        min_disparity=min_disparity,
        block_size=block_size,
        p1=p1,
        p2=p2,
        p2_step=p2_step,
        paths=paths,
        subpixel=subpixel,
        uniqueness_ratio=uniqueness_ratio,
        lr_max_diff=lr_max_diff,
        median=median,
        speckle_window=speckle_window,
        speckle_range=speckle_range,
        border=border,
        fill=fill,
        max_memory_mb=max_memory_mb,
        threads=threads,
        return_confidence=return_confidence,
        channel_order=channel_order,
        intensity_range=intensity_range,
    )
    return matcher.compute(left, right)
