"""Dense block-matching disparity, natively: :func:`block_match` and :class:`StereoMatcher`.

The matcher compares a square block around each pixel of the left image with blocks along the
same row of the right image, ``min_disparity .. min_disparity + num_disparities - 1`` pixels to
the left, and keeps the disparity of least cost (the lowest disparity on a tie). Everything is
integer arithmetic up to the sub-pixel step, so the native kernel and the numpy oracle
(:func:`stereodepth.reference.block_match`) agree exactly on the integer disparities and the
validity; the sub-pixel step is the same float32 formula in both (the tests allow 1e-3 px).

Steps, in the kernel and in the oracle alike:

1. Grey: uint8 grey images are used as they are; RGB (uint8, (H, W, 3)) becomes
   ``(9798 R + 19235 G + 3735 B + 16384) >> 15``, OpenCV's ``COLOR_RGB2GRAY`` bit for bit.
   The channels are taken as R, G, B unless ``channel_order="bgr"`` says they are B, G, R
   (OpenCV's ``cv2.imread`` order); the grey image is then OpenCV's ``COLOR_BGR2GRAY``.
   uint16 grey images are first stretched from the pair's joint range onto the scale of a
   uint8 image: with ``lo`` and ``hi`` the least and the largest value of both images, each
   value ``v`` becomes ``((v - lo) * 65280 + (hi - lo) // 2) // (hi - lo)`` (integer
   arithmetic, rounded to nearest, ``lo`` -> 0, ``hi`` -> 65280 = 255 * 256, monotone, and
   strictly increasing when ``hi - lo <= 65280``: a full-range 16-bit pair merges one level
   in 256); a constant pair is used as it is. After the 8-bit shift of step 2 the SAD
   prefilter and the texture check see the grey levels of the pair's min-max stretch to
   0..255, and census (which only compares) sees the same order. So a 12-bit image
   (0..4095, or v * 16), a narrow-band thermal image (7000 + 6 v) or 8-bit values stored in
   uint16 are matched at the scale of their min-max stretch, and an encoding ``a * v + b``
   of a uint8 pair that spans 0..255 (v * 16, v * 256, v * 257, 7000 + 6 v, ...) gives
   exactly the uint8 pair's disparity. The range is the pair's own, frame by frame, unless
   ``intensity_range=(lo, hi)`` fixes it (a sensor's band, or one scale for every frame of a
   stream): values below ``lo`` or above ``hi`` are then first clipped to it.
2. Pixel cost. ``cost="census"``: a census transform over the border of the 5x5 window
   (the 16 pixels two away from the centre, one bit each: "neighbour < centre"), compared by
   Hamming distance, 0..16 per pixel. On the shared scenes this ring is more accurate than
   the full 5x5 census (24 bits) and cheaper. ``cost="sad"``: the absolute difference of
   the x-Sobel-prefiltered images ``clip(sobel_x, -31, 31) + 31``, 0..62 per pixel, as
   OpenCV's StereoBM; for uint16 images (stretched as in step 1) the Sobel response is first
   shifted right by 8 bits, which puts it on the scale of the uint8 min-max stretch.
   Pixels outside the image repeat the nearest edge pixel (for the neighbours of the census
   and the Sobel filter, and for a right-image pixel left of column 0 or right of the last).
3. Aggregation: the sum of pixel costs over a ``block_size`` x ``block_size`` block, the block
   clamped at the image border the same way (edge rows and columns repeat).
4. Winner: the disparity of least block cost; the lowest disparity on a tie.
5. Validity (NaN where any check fails):

   - the border band (``border="clip"``, the default): a pixel whose search range leaves the
     right image (the left ``min_disparity + num_disparities - 1`` columns, and for a negative
     ``min_disparity`` the right ``-min_disparity`` ones) is matched over the disparities ``d``
     whose ``x - d`` lies in ``[0, W)``; the others never win, count for neither the
     uniqueness check nor the sub-pixel fit (which needs both neighbours inside). The pixel
     is NaN when no ``d`` is inside, or when every ``d`` inside lies within one disparity of
     the winner (no second-best cost to tell the winner from: the first two or three
     columns, whose true match has mostly left the right image). ``border="opencv"`` makes
     every such pixel NaN, as OpenCV's StereoBM and StereoSGBM do;
   - texture: the block sum of ``min(|sobel_x|, 31)`` (the clipped gradient, on the same scale
     as the SAD prefilter) must be ``>= texture_threshold * block_size**2``, so
     ``texture_threshold`` is a mean gradient per pixel in grey levels (of 0..255; for uint16,
     of the pair's min-max stretch to 0..255, as in step 1); 0 turns it off;
   - uniqueness: every cost more than one disparity away from the winner must exceed the
     winning cost by more than ``uniqueness_ratio`` percent:
     ``second * 100 > best * (100 + uniqueness_ratio)``; 0 turns it off;
   - left-right consistency: the right image's own winner at ``x - d`` (the least cost along
     the other diagonal of the same costs, lowest disparity on a tie) must be within
     ``lr_max_diff`` pixels of ``d``; None turns it off.
6. Sub-pixel: the winner ``d`` moves by ``delta`` fitted to the costs ``c0, c1, c2`` at
   ``d - 1, d, d + 1``, in float32: ``"parabola"``:
   ``delta = (c0 - c2) / (2 (c0 + c2 - 2 c1))``; ``"equiangular"`` (a V fit):
   ``delta = (c0 - c2) / (2 max(c0 - c1, c2 - c1))``. No move at either end of the range, or
   where the denominator is 0.
7. Speckle filter (``speckle_window > 0``): 4-connected regions of valid pixels whose
   neighbours differ by at most ``speckle_range`` pixels are removed (NaN) when they have at
   most ``speckle_window`` pixels, as OpenCV's ``filterSpeckles``.

Confidence (``return_confidence=True``): ``(second - best) / second`` in ``[0, 1]``, where
``second`` is the least cost more than one disparity away from the winner: 0 for a winner no
better than another candidate, near 1 for a sharp, unique minimum; 1 when no candidate lies
more than one disparity away (``num_disparities <= 3``), 0 where the disparity is NaN.
Thresholding it is the uniqueness check: ``confidence > r / (100 + r)`` is
``uniqueness_ratio = r`` (up to float32 rounding at the threshold itself).

Defaults, chosen by measuring on the shared scenes (bench/README.md): census, block 9,
equiangular sub-pixel fit, uniqueness 2 %, left-right check within 1 px, speckle filter of
100 px at 1 px, no texture threshold, the border band matched (``border="clip"``). On the ten
scenes that is a mean bad-2 of 19.4 % (holes count as bad; 25.7 % with ``border="opencv"``)
against 32.8 % for OpenCV's StereoBM at its better of blocks 9 and 15, and a mean bad-0.5
among estimated pixels of 12.8 % against 15.0 %.

Limits: block costs are accumulated in 16 bits, so ``block_size`` is at most 63 for census and
31 for SAD (the largest block sum then stays below 65535); ``num_disparities`` is at most
4096, ``|min_disparity|`` at most 32768, and the image width times ``num_disparities`` rounded
up to a multiple of 16 (the SIMD kernels' lanes; :data:`MAX_WIDTH_TIMES_DISPARITIES`) below
2**30, on every instruction set alike; a search range must reach into the image (some
disparity in ``-(W - 1) .. W - 1``), for both matchers and their oracles. Memory is
O(W * num_disparities) per thread plus a few bytes per pixel; there is never a full cost
volume. Rows are split into one band per thread (an idle thread takes over half of the rows
another has left); the output does not depend on the number of threads or on how the rows
were shared.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from . import _core
from . import _validate as check

__all__ = [
    "MAX_BLOCK_SIZE",
    "MAX_NUM_DISPARITIES",
    "StereoMatcher",
    "block_match",
    "to_opencv_disparity",
]

#: The largest block size per cost (block costs are summed in 16 bits).
MAX_BLOCK_SIZE = {"census": 63, "sad": 31}
#: The largest ``num_disparities``.
MAX_NUM_DISPARITIES = 4096
#: The largest ``|min_disparity|``.
MAX_ABS_MIN_DISPARITY = 32768
#: The image width times ``num_disparities`` rounded up to a multiple of
#: :data:`DISPARITY_LANES` must be below this (the kernels' per-thread buffers).
MAX_WIDTH_TIMES_DISPARITIES = 2**30
#: The lanes the widest kernels (AVX2, AVX-512) round ``num_disparities`` up to.
DISPARITY_LANES = 16
#: The largest per-pixel cost of each cost function.
PIXEL_COST_MAX = {"census": 16, "sad": 62}
#: The cap of the x-Sobel prefilter (OpenCV's preFilterCap default).
PREFILTER_CAP = 31
#: The census window: its border, 16 pixels for 5x5, gives the bits.
CENSUS_WINDOW = 5

#: The top of the scale a uint16 pair is stretched to (255 * 256: after the 8-bit shift of
#: the Sobel response, the grey levels of a uint8 image).
UINT16_STRETCH_TOP = 255 * 256
#: The channel orders of (H, W, 3) images.
CHANNEL_ORDERS = ("rgb", "bgr")

_SUBPIXEL_MODES = ("parabola", "equiangular")
#: The sub-pixel fit that ``subpixel=True`` chooses for each cost (see bench/README.md).
DEFAULT_SUBPIXEL = {"census": "equiangular", "sad": "equiangular"}

# Defaults (chosen by measuring on the shared scenes; see bench/README.md).
DEFAULT_BLOCK_SIZE = 9
DEFAULT_UNIQUENESS_RATIO = 2.0
DEFAULT_TEXTURE_THRESHOLD = 0.0
DEFAULT_SPECKLE_WINDOW = 100
DEFAULT_SPECKLE_RANGE = 1.0


def search_reaches(min_disparity: int, num_disparities: int, cols: int) -> bool:
    """Whether the search range has some disparity in ``-(cols - 1) .. cols - 1``, the only
    ones pixel x can be matched at (x - d inside an image ``cols`` pixels wide)."""
    return min_disparity < cols and min_disparity + num_disparities - 1 > -cols


class MatcherOptions:
    """The parameters every matcher takes (the search range, the decision's checks and
    filters, the input conventions), checked and resolved once for all of them; each matcher's
    options class adds its own (BlockMatchOptions, semi_global.SemiGlobalOptions)."""

    __slots__ = (
        "border",
        "channel_order",
        "intensity_range",
        "lr_max_diff",
        "min_disparity",
        "num_disparities",
        "return_confidence",
        "speckle_range",
        "speckle_window",
        "subpixel",
        "threads",
        "uniqueness_factor",
        "uniqueness_ratio",
    )

    def _check_range(self, num_disparities: Any, min_disparity: Any) -> None:
        nd = check.integer("num_disparities", num_disparities)
        if not 1 <= nd <= MAX_NUM_DISPARITIES:
            raise ValueError(
                f"num_disparities must be an integer in [1, {MAX_NUM_DISPARITIES}], got {nd}"
            )
        self.num_disparities = nd
        md = check.integer("min_disparity", min_disparity)
        if abs(md) > MAX_ABS_MIN_DISPARITY:
            raise ValueError(
                f"min_disparity must be an integer in [-{MAX_ABS_MIN_DISPARITY}, "
                f"{MAX_ABS_MIN_DISPARITY}], got {md}"
            )
        self.min_disparity = md

    def _check_decision(
        self,
        *,
        subpixel: Any,
        default_subpixel: str,
        uniqueness_ratio: Any,
        lr_max_diff: Any,
        speckle_window: Any,
        speckle_range: Any,
    ) -> None:
        if isinstance(subpixel, (bool, np.bool_)):
            self.subpixel: str | None = default_subpixel if subpixel else None
        elif isinstance(subpixel, str):
            if subpixel not in _SUBPIXEL_MODES:
                raise ValueError(
                    f"subpixel must be True, False, 'parabola' or 'equiangular', got {subpixel!r}"
                )
            self.subpixel = subpixel
        else:
            raise TypeError(
                "subpixel must be True, False, 'parabola' or 'equiangular', "
                f"got {type(subpixel).__name__} {subpixel!r}"
            )
        self.uniqueness_ratio = check.non_negative("uniqueness_ratio", uniqueness_ratio)
        # The check is second * 100 > best * uniqueness_factor; 0 means off.
        self.uniqueness_factor = 100.0 + self.uniqueness_ratio if self.uniqueness_ratio > 0 else 0.0
        if lr_max_diff is None:
            self.lr_max_diff: float | None = None
        else:
            self.lr_max_diff = check.non_negative("lr_max_diff", lr_max_diff)
        self.speckle_window = check.integer(
            "speckle_window", speckle_window, minimum=0, maximum=check.MAX_NATIVE_INT
        )
        self.speckle_range = check.non_negative("speckle_range", speckle_range)

    def _check_io(
        self,
        *,
        threads: Any,
        return_confidence: Any,
        channel_order: Any,
        intensity_range: Any,
        border: Any,
    ) -> None:
        self.threads = check.threads(threads)
        self.return_confidence = check_flag("return_confidence", return_confidence)
        self.channel_order = check_channel_order(channel_order)
        self.intensity_range = check_intensity_range(intensity_range)
        self.border = check_border(border)

    def check_size(self, rows: int, cols: int) -> None:
        """Raises ValueError when the matcher refuses a pair of ``rows`` x ``cols`` pixels
        whatever its values, before the pair is copied or stretched; each matcher's options
        class adds what it refuses. Every matcher refuses a search range wholly outside the
        image: pixel ``x`` looks for its match at ``x - d`` in the right image, so only
        disparities in ``[-(cols - 1), cols - 1]`` can ever be matched, and a range of none of
        them (``min_disparity >= cols``, or ``min_disparity + num_disparities - 1 <= -cols``)
        would give a map that is NaN everywhere, most often from a typo or a crop."""
        low = self.min_disparity
        high = low + self.num_disparities - 1
        if not search_reaches(low, self.num_disparities, cols):
            raise ValueError(
                f"min_disparity={low} with num_disparities={self.num_disparities} searches "
                f"disparities {low} to {high}, none of which lies inside an image {cols} "
                f"pixels wide (pixel x is matched at x - d, so only {-(cols - 1)} to {cols - 1} "
                f"can be): every pixel would be NaN; check min_disparity"
            )

    def stretch_native(
        self, left: np.ndarray, right: np.ndarray, intensity_range: tuple[int, int] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """:func:`stretch_uint16_pair`'s arrays (the same values) from the native kernel, on
        ``self.threads`` threads: the range in one pass over the pair, then a float quotient
        corrected by the exact remainder where numpy divides (a 1280 x 720 pair with 2
        threads: about 0.6-0.8 ms, numpy 2.5 ms)."""
        out: tuple[np.ndarray, np.ndarray] = _core._stretch_uint16_pair(
            left, right, intensity_range, self.threads
        )
        return out


def check_flag(name: str, value: Any) -> bool:
    """``value`` as a bool (bool or numpy bool only); TypeError naming ``name`` otherwise."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be a bool, got {type(value).__name__} {value!r}")
    return bool(value)


class BlockMatchOptions(MatcherOptions):
    """The checked, resolved parameters shared by the native kernel and the numpy oracle."""

    __slots__ = ("block_size", "cost", "texture_sum_min", "texture_threshold")

    def __init__(
        self,
        *,
        num_disparities: Any,
        min_disparity: Any = 0,
        block_size: Any = DEFAULT_BLOCK_SIZE,
        cost: Any = "census",
        subpixel: Any = True,
        uniqueness_ratio: Any = DEFAULT_UNIQUENESS_RATIO,
        texture_threshold: Any = DEFAULT_TEXTURE_THRESHOLD,
        lr_max_diff: Any = 1.0,
        speckle_window: Any = DEFAULT_SPECKLE_WINDOW,
        speckle_range: Any = DEFAULT_SPECKLE_RANGE,
        threads: Any = None,
        return_confidence: Any = False,
        channel_order: Any = "rgb",
        intensity_range: Any = None,
        border: Any = "clip",
    ) -> None:
        if not isinstance(cost, str):
            raise TypeError(f"cost must be 'census' or 'sad', got {type(cost).__name__} {cost!r}")
        if cost not in MAX_BLOCK_SIZE:
            raise ValueError(f"cost must be 'census' or 'sad', got {cost!r}")
        self.cost: str = cost

        self._check_range(num_disparities, min_disparity)

        bs = check.integer("block_size", block_size)
        limit = MAX_BLOCK_SIZE[cost]
        if bs < 3 or bs % 2 == 0 or bs > limit:
            raise ValueError(
                f"block_size must be an odd integer in [3, {limit}] for cost={cost!r} "
                f"(block costs are summed in 16 bits), got {bs}"
            )
        self.block_size = bs

        self._check_decision(
            subpixel=subpixel,
            default_subpixel=DEFAULT_SUBPIXEL[cost],
            uniqueness_ratio=uniqueness_ratio,
            lr_max_diff=lr_max_diff,
            speckle_window=speckle_window,
            speckle_range=speckle_range,
        )
        self.texture_threshold = check.non_negative("texture_threshold", texture_threshold)
        # The block's gradient sum must be >= texture_sum_min (computed once, here, so the
        # kernel and the oracle compare against the same double).
        self.texture_sum_min = self.texture_threshold * float(bs * bs)
        self._check_io(
            threads=threads,
            return_confidence=return_confidence,
            channel_order=channel_order,
            intensity_range=intensity_range,
            border=border,
        )

    def check_size(self, rows: int, cols: int) -> None:
        """The width limit of the module docstring: ``cols`` times ``num_disparities``
        rounded up to a multiple of 16 below 2**30, on every instruction set (the kernels'
        own guard takes the same rule), checked here before a view is copied or a uint16
        pair stretched; and the search range of :meth:`MatcherOptions.check_size`."""
        super().check_size(rows, cols)
        rounded = -(-self.num_disparities // DISPARITY_LANES) * DISPARITY_LANES
        if cols * rounded >= MAX_WIDTH_TIMES_DISPARITIES:
            raise ValueError(
                f"the image width times num_disparities must be below 2^30 with "
                f"num_disparities rounded up to a multiple of {DISPARITY_LANES} (the kernels' "
                f"buffers), got {cols} x {self.num_disparities} ({cols} x {rounded} = "
                f"{cols * rounded}): match a narrower (cropped or downscaled) pair or lower "
                f"num_disparities"
            )

    def as_dict(self) -> dict[str, Any]:
        """The public parameters, resolved (``subpixel`` as the fit's name or None)."""
        return {
            "num_disparities": self.num_disparities,
            "min_disparity": self.min_disparity,
            "block_size": self.block_size,
            "cost": self.cost,
            "subpixel": self.subpixel if self.subpixel is not None else False,
            "uniqueness_ratio": self.uniqueness_ratio,
            "texture_threshold": self.texture_threshold,
            "lr_max_diff": self.lr_max_diff,
            "speckle_window": self.speckle_window,
            "speckle_range": self.speckle_range,
            "threads": self.threads,
            "return_confidence": self.return_confidence,
            "channel_order": self.channel_order,
            "intensity_range": self.intensity_range,
            "border": self.border,
        }


_RANGE_RULE = "None or two integers (lo, hi) with 0 <= lo < hi <= 65535"


def check_intensity_range(intensity_range: Any) -> tuple[int, int] | None:
    """None, or ``(lo, hi)`` as two ints with ``0 <= lo < hi <= 65535``; TypeError /
    ValueError naming ``intensity_range`` otherwise."""
    if intensity_range is None:
        return None
    if not isinstance(intensity_range, (tuple, list)) or len(intensity_range) != 2:
        raise TypeError(
            f"intensity_range must be {_RANGE_RULE}, got {type(intensity_range).__name__} "
            f"{intensity_range!r}"
        )
    for v in intensity_range:
        if not isinstance(v, (int, np.integer)) or isinstance(v, (bool, np.bool_)):
            raise TypeError(
                f"intensity_range must be {_RANGE_RULE}, got {intensity_range!r} "
                f"(a {type(v).__name__})"
            )
    lo, hi = int(intensity_range[0]), int(intensity_range[1])
    if not 0 <= lo < hi <= 65535:
        raise ValueError(f"intensity_range must be {_RANGE_RULE}, got {intensity_range!r}")
    return lo, hi


def check_channel_order(channel_order: Any) -> str:
    """``"rgb"`` or ``"bgr"``; TypeError / ValueError naming ``channel_order`` otherwise."""
    if not isinstance(channel_order, str):
        raise TypeError(
            f"channel_order must be 'rgb' or 'bgr', got {type(channel_order).__name__} "
            f"{channel_order!r}"
        )
    if channel_order not in CHANNEL_ORDERS:
        raise ValueError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
    return channel_order


def check_border(border: Any) -> str:
    """The border rule of both matchers: ``"clip"`` or ``"opencv"``."""
    if not isinstance(border, str):
        raise TypeError(
            f"border must be 'clip' or 'opencv', got {type(border).__name__} {border!r}"
        )
    if border not in ("clip", "opencv"):
        raise ValueError(f"border must be 'clip' or 'opencv', got {border!r}")
    return border


_IMAGE_RULE = "2-D uint8 or uint16 grey, or (H, W, 3) uint8 RGB"


def as_image(image: Any, name: str, *, contiguous: bool = True) -> np.ndarray:
    """Checks dtype and shape; returns a C-contiguous array in the machine's byte order
    (copying only when needed: a big-endian uint16 image, as FITS or PGM readers give, is
    a uint16 image); with ``contiguous=False`` the array as it is, not copied (in either byte
    order: :func:`check_pair` converts it once the size is checked)."""
    if not isinstance(image, np.ndarray):
        raise TypeError(
            f"{name} must be a numpy.ndarray ({_IMAGE_RULE}), got {type(image).__name__}"
        )
    check.not_masked(name, image)
    dtype = image.dtype.newbyteorder("=")  # what the values are, in either byte order
    if dtype not in (np.uint8, np.uint16):
        raise TypeError(f"{name} must be {_IMAGE_RULE}, got dtype {image.dtype}")
    if image.ndim == 3:
        if image.shape[2] != 3 or dtype != np.uint8:
            raise ValueError(f"{name} must be {_IMAGE_RULE}, got shape {image.shape} {dtype}")
    elif image.ndim != 2:
        raise ValueError(f"{name} must be {_IMAGE_RULE}, got shape {image.shape}")
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(
            f"{name} must have at least one row and one column, got shape {image.shape}"
        )
    return np.ascontiguousarray(check.native_order(image)) if contiguous else image


def check_pair(
    left: Any, right: Any, check_size: Callable[[int, int], None] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Checks both images and that they agree, then ``check_size(rows, cols)`` when given
    (a matcher's size limit, before any copy); returns them C-contiguous, values unchanged."""
    left_arr = as_image(left, "left", contiguous=False)
    right_arr = as_image(right, "right", contiguous=False)
    if left_arr.shape != right_arr.shape:
        raise ValueError(
            f"left and right must have the same shape, got {left_arr.shape} and {right_arr.shape}"
        )
    if left_arr.dtype.newbyteorder("=") != right_arr.dtype.newbyteorder("="):
        raise TypeError(
            f"left and right must have the same dtype, got {left_arr.dtype} and {right_arr.dtype}"
        )
    if check_size is not None:
        check_size(left_arr.shape[0], left_arr.shape[1])
    # The byte order too only now: a big-endian pair was converted, whole, before the check.
    return (
        np.ascontiguousarray(check.native_order(left_arr)),
        np.ascontiguousarray(check.native_order(right_arr)),
    )


def stretch_uint16_pair(
    left: np.ndarray, right: np.ndarray, intensity_range: tuple[int, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A uint16 pair on the scale of its min-max stretch to uint8 (step 1 of the module
    docstring): from the joint range ``[lo, hi]`` (or the given ``intensity_range``, values
    outside it clipped) onto ``0 .. 65280``, rounded to the nearest integer (halves up); a
    constant pair without ``intensity_range`` is returned as it is. New arrays otherwise;
    the inputs are not modified."""
    if intensity_range is None:
        lo = int(min(left.min(), right.min()))
        span = int(max(left.max(), right.max())) - lo
        if span == 0:
            return left, right
    else:
        lo, hi = intensity_range
        span = hi - lo
        left = np.clip(left, lo, hi)
        right = np.clip(right, lo, hi)

    def one(image: np.ndarray) -> np.ndarray:
        # In place, in uint32: 65535 * 65280 + 32767 < 2**32.
        v = np.subtract(image, lo, dtype=np.uint32)
        v *= UINT16_STRETCH_TOP
        v += span // 2
        v //= span
        out: np.ndarray = v.astype(np.uint16)
        return out

    return one(left), one(right)


def as_pair(
    left: Any,
    right: Any,
    *,
    channel_order: str = "rgb",
    intensity_range: tuple[int, int] | None = None,
    stretch: Any = None,
    check_size: Callable[[int, int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The pair as every matcher takes it: checked (:func:`check_pair`), C-contiguous, with
    ``channel_order`` checked (colour images keep their channels in the order given: the native
    kernels and the oracles' ``grey`` weigh them by it, so a B, G, R frame is never copied) and
    uint16 pairs stretched to the scale of uint8 (:func:`stretch_uint16_pair`, over
    ``intensity_range`` when given, or ``stretch(left, right, intensity_range)`` in its place:
    the native matchers pass :meth:`MatcherOptions.stretch_native`, the oracles keep numpy).
    The rules are step 1 of the module docstring. ``check_size`` is :func:`check_pair`'s.
    Raises ValueError when ``intensity_range`` is given for uint8 images (they are matched as
    they are)."""
    check_channel_order(channel_order)
    fixed = check_intensity_range(intensity_range)
    left_arr, right_arr = check_pair(left, right, check_size)
    if left_arr.dtype == np.uint16:
        left_arr, right_arr = (stretch or stretch_uint16_pair)(left_arr, right_arr, fixed)
    elif fixed is not None:
        raise ValueError(
            f"intensity_range applies to uint16 images (uint8 images are matched as they are), "
            f"got {fixed!r} with uint8 images"
        )
    return left_arr, right_arr


class FixedParameters:
    """A matcher's parameters are fixed when it is made: assigning one (``m.num_disparities
    = 128``, the habit of OpenCV's setters) is an AttributeError saying so, where it made a new
    attribute that the matcher never read. Make a new matcher instead (``m.params`` gives the
    current parameters).

    A matcher pickles (and copies) as its parameters and the ``isa`` it was asked for: the copy
    is a new matcher with buffers of its own, so that one can be sent to a process pool or a
    Dask worker, where ``isa="auto"`` and ``threads=None`` pick what that machine has. A
    subclass's copy is made without calling its ``__init__`` (as pickle does for any object)
    and gets its other attributes back."""

    __slots__ = ()

    if TYPE_CHECKING:  # what the matchers define
        _isa_arg: str

    def __reduce__(self) -> tuple[Any, tuple[Any, ...], dict[str, Any]]:
        # A subclass's own attributes, in __dict__ or in slots of its own.
        state = dict(getattr(self, "__dict__", {}))
        for klass in type(self).__mro__:
            for name in getattr(klass, "__slots__", ()):
                if name not in _NATIVE_STATE and hasattr(self, name):
                    state[name] = getattr(self, name)
        # The matcher's own parameters (a subclass may override ``params``).
        options: Any = object.__getattribute__(self, "_options")
        return (_remake_matcher, (type(self), options.as_dict(), self._isa_arg), state)

    def __setstate__(self, state: dict[str, Any]) -> None:
        for name, value in state.items():
            object.__setattr__(self, name, value)

    def __setattr__(self, name: str, value: Any) -> None:
        if name.startswith("_"):
            object.__setattr__(self, name, value)
            return
        kind = type(self).__name__
        raise AttributeError(
            f"{kind}'s parameters are fixed when it is made: make a new one, "
            f"{kind}(**{{**matcher.params, {name!r}: {value!r}}}), instead of assigning "
            f"{name} = {value!r}"
        )


# The attributes every matcher makes in __init__ (the rest is a subclass's).
_NATIVE_STATE = ("_isa_arg", "_native", "_options", "__dict__", "__weakref__")


def _remake_matcher(cls: Any, params: dict[str, Any], isa: str) -> Any:
    """A new ``cls`` with ``params`` and ``isa`` (how a pickled matcher is made again), set up by
    the matcher class it derives from (StereoMatcher or SemiGlobalMatcher), not by a
    subclass's ``__init__``, whose signature may differ."""
    base = next(k for k in cls.__mro__ if FixedParameters in k.__bases__)
    obj = cls.__new__(cls)
    base.__init__(obj, **params, isa=isa)
    return obj


class StereoMatcher(FixedParameters):
    """The block matcher as an object for per-frame use.

    The parameters are those of :func:`block_match` (``return_confidence``,
    ``channel_order`` and ``intensity_range`` included), checked
    once here; :meth:`compute` then matches a pair, reusing the matcher's internal buffers from
    one frame to the next. Calls from several threads on one matcher are safe (they take turns);
    use one matcher per thread to match in parallel.

    ``isa`` picks the instruction set of the kernel: ``"auto"`` (the best this CPU runs, capped
    by the environment variable STEREODEPTH_ISA), ``"baseline"``, ``"avx2"`` or ``"avx512"``.
    Every choice gives the same output; it exists for testing and benchmarking.

    The parameters are fixed: assigning one is an AttributeError (make a new matcher). A
    matcher pickles as its parameters and ``isa`` (see :class:`FixedParameters`).
    """

    __slots__ = ("_isa_arg", "_native", "_options")

    def __init__(
        self,
        *,
        num_disparities: int,
        min_disparity: int = 0,
        block_size: int = DEFAULT_BLOCK_SIZE,
        cost: str = "census",
        subpixel: bool | str = True,
        uniqueness_ratio: float = DEFAULT_UNIQUENESS_RATIO,
        texture_threshold: float = DEFAULT_TEXTURE_THRESHOLD,
        lr_max_diff: float | None = 1.0,
        speckle_window: int = DEFAULT_SPECKLE_WINDOW,
        speckle_range: float = DEFAULT_SPECKLE_RANGE,
        threads: int | None = None,
        return_confidence: bool = False,
        channel_order: str = "rgb",
        intensity_range: tuple[int, int] | None = None,
        border: str = "clip",
        isa: str = "auto",
    ) -> None:
        self._options = BlockMatchOptions(
            num_disparities=num_disparities,
            min_disparity=min_disparity,
            block_size=block_size,
            cost=cost,
            subpixel=subpixel,
            uniqueness_ratio=uniqueness_ratio,
            texture_threshold=texture_threshold,
            lr_max_diff=lr_max_diff,
            speckle_window=speckle_window,
            speckle_range=speckle_range,
            threads=threads,
            return_confidence=return_confidence,
            channel_order=channel_order,
            intensity_range=intensity_range,
            border=border,
        )
        if not isinstance(isa, str):
            raise TypeError(f"isa must be a str, got {type(isa).__name__} {isa!r}")
        self._isa_arg = isa
        o = self._options
        self._native = _core.BlockMatcher(
            o.num_disparities,
            o.min_disparity,
            o.block_size,
            o.cost,
            o.subpixel or "none",
            o.uniqueness_ratio,
            o.texture_threshold,
            -1.0 if o.lr_max_diff is None else o.lr_max_diff,
            o.speckle_window,
            o.speckle_range,
            o.threads,
            isa,
            o.border == "clip",
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
        return f"StereoMatcher({', '.join(args)})"

    def compute(self, left: Any, right: Any) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """The float32 disparity of ``left`` (and the confidence, if the matcher was made
        with ``return_confidence=True``); see :func:`block_match`."""
        return run_native(self._native, self._options, left, right)


def run_native(
    native: Any, options: Any, left: Any, right: Any, finish: Any = None
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """What both matchers' ``compute`` do: the pair checked and converted by :func:`as_pair`
    (with ``options.channel_order`` and ``options.intensity_range``; a uint16 pair is stretched
    by :meth:`MatcherOptions.stretch_native`), the native kernel run into new float32 maps
    with the channel order (a B, G, R pair is read as it is: a reversed copy added 40 % to the
    time of matching a 1280 x 720 pair), ``finish(disparity)`` if given, and the disparity
    returned (with the confidence when ``options.return_confidence``). The sizes the matcher
    refuses (``options.check_size``, and the native matcher's ``check_size`` where it has one:
    the semi-global matcher's memory estimate) are refused before the pair is copied."""

    def check_size(rows: int, cols: int) -> None:
        options.check_size(rows, cols)
        if hasattr(native, "check_size"):
            native.check_size(rows, cols)

    left_arr, right_arr = as_pair(
        left,
        right,
        channel_order=options.channel_order,
        intensity_range=options.intensity_range,
        stretch=options.stretch_native,
        check_size=check_size,
    )
    shape = left_arr.shape[:2]
    disparity = np.empty(shape, dtype=np.float32)
    confidence = np.empty(shape, dtype=np.float32) if options.return_confidence else None
    native.compute(left_arr, right_arr, disparity, confidence, options.channel_order)
    if finish is not None:
        finish(disparity)
    if confidence is not None:
        return disparity, confidence
    return disparity


#: block_match keeps the calling thread's matcher (its buffers) for pairs up to this size.
KEEP_MATCHER_MAX_PIXELS = 8_000_000


def block_match(
    left: Any,
    right: Any,
    *,
    num_disparities: int,
    min_disparity: int = 0,
    block_size: int = DEFAULT_BLOCK_SIZE,
    cost: str = "census",
    subpixel: bool | str = True,
    uniqueness_ratio: float = DEFAULT_UNIQUENESS_RATIO,
    texture_threshold: float = DEFAULT_TEXTURE_THRESHOLD,
    lr_max_diff: float | None = 1.0,
    speckle_window: int = DEFAULT_SPECKLE_WINDOW,
    speckle_range: float = DEFAULT_SPECKLE_RANGE,
    threads: int | None = None,
    return_confidence: bool = False,
    channel_order: str = "rgb",
    intensity_range: tuple[int, int] | None = None,
    border: str = "clip",
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Dense disparity of the left image by block matching, natively.

    Parameters
    ----------
    left, right
        The rectified pair, the same shape and dtype: (H, W) uint8 or uint16 grey, or
        (H, W, 3) uint8 colour, R, G, B unless ``channel_order`` says otherwise (turned into
        grey as OpenCV's ``COLOR_RGB2GRAY``). A uint16 pair is first stretched from its joint
        [min, max] onto 0..65280 = 255 * 256, the scale of uint8, so 12-bit (0..4095 or
        v * 16) and narrow-band (thermal) images keep their detail: every cost and
        ``texture_threshold`` then see the grey levels of the pair's min-max stretch to
        0..255. The exact rule is step 1 of :mod:`stereodepth.matching`.
    num_disparities
        How many disparities to search, any integer in [1, 4096].
    min_disparity
        The smallest disparity searched, in pixels; may be negative. A range with no
        disparity in ``-(W - 1) .. W - 1`` for an image W pixels wide (no pixel has a
        candidate inside the right image) is refused with ValueError.
    block_size
        The side of the square matching block, odd, >= 3 (at most 63 for census, 31 for SAD).
        The cost per pixel does not depend on it.
    cost
        ``"census"`` (census over the border of a 5x5 window, Hamming distance; robust to gain
        and bias between the cameras) or ``"sad"`` (absolute differences of the
        x-Sobel-prefiltered images, as OpenCV's StereoBM).
    subpixel
        Refine the winning disparity from its neighbours' costs: True for the fit measured
        best for the cost, ``"parabola"`` or ``"equiangular"``, or False for integers.
    uniqueness_ratio
        Percent by which every cost more than one disparity away must exceed the winner's;
        0 turns the check off.
    texture_threshold
        Least mean clipped x-gradient per pixel of the block (grey levels of 0..255; for uint16,
        of the pair's min-max stretch); flatter blocks are NaN. 0 turns the check off.
    lr_max_diff
        Largest difference, in pixels, between the left disparity and the right image's own
        disparity at the matched pixel; None turns the check off.
    speckle_window, speckle_range
        Remove connected regions of at most ``speckle_window`` pixels whose neighbouring
        disparities differ by at most ``speckle_range`` px; ``speckle_window=0`` turns it off.
    threads
        Threads to split the rows over; None or 0 for every core available (the affinity
        mask, lowered to a container's CPU quota: ``stereodepth.build_info()
        ["default_threads"]``). The output does not depend on it.
    return_confidence
        Also return the confidence map (see below).
    channel_order
        The order of the channels of (H, W, 3) images: ``"rgb"`` (Pillow,
        :func:`stereodepth.io.read_image`, imageio) or ``"bgr"`` (OpenCV's ``cv2.imread``,
        ``cv2.VideoCapture``); with ``"bgr"`` the grey image is OpenCV's ``COLOR_BGR2GRAY``.
        Grey images ignore it.
    intensity_range
        For uint16 images: None (default) stretches each pair from its own joint [min, max];
        ``(lo, hi)``, integers with ``0 <= lo < hi <= 65535``, stretches every pair from that
        range instead, values outside it clipped: a sensor's band (``(0, 4095)`` for 12 bits)
        or one scale for every frame of a stream, so that ``texture_threshold`` and the SAD
        costs mean the same from frame to frame. ValueError for uint8 images.
    border
        ``"clip"``: pixels near the left edge, whose search range leaves the right image, are
        matched over the disparities inside it (NaN where those leave the winner no rival
        more than one disparity away); ``"opencv"``: they are NaN, as OpenCV's.

    Returns
    -------
    The float32 (H, W) disparity in pixels, NaN where there is no reliable match; with
    ``return_confidence=True``, ``(disparity, confidence)``, the confidence float32 in
    [0, 1]: ``(second - best) / second`` from the cost curve, where ``second`` is the least
    cost more than one disparity away from the winner (0 where the disparity is NaN; 1 when
    there is no such cost, which happens only with ``num_disparities <= 3``: with so few
    candidates the confidence says nothing).

    The steps, the validity rules and the limits are described in :mod:`stereodepth.matching`.
    The GIL is released while the kernel runs. Ctrl-C during a call on the main thread stops
    the kernel within a few rows and raises KeyboardInterrupt (calls of at least 16 M pixels x
    disparities, while Python's default SIGINT handler is installed). The calling thread keeps
    the matcher of its last call (and its buffers, tens of MB for a 2 MP pair) while the
    parameters stay the same, so a loop of calls costs what :meth:`StereoMatcher.compute`
    does; it is released when the parameters change, the thread ends, or after a pair of more
    than ``KEEP_MATCHER_MAX_PIXELS`` (8 MP). A :class:`StereoMatcher` keeps its buffers
    explicitly.

    Raises TypeError for a wrong type or dtype (images, parameters) and ValueError for a wrong
    value or shape, naming the parameter and what was received.
    """
    from ._methods import release_thread_matcher, thread_matcher

    matcher: StereoMatcher = thread_matcher(
        "bm",
        num_disparities=num_disparities,
        min_disparity=min_disparity,
        block_size=block_size,
        cost=cost,
        subpixel=subpixel,
        uniqueness_ratio=uniqueness_ratio,
        texture_threshold=texture_threshold,
        lr_max_diff=lr_max_diff,
        speckle_window=speckle_window,
        speckle_range=speckle_range,
        threads=threads,
        return_confidence=return_confidence,
        channel_order=channel_order,
        intensity_range=intensity_range,
        border=border,
    )
    try:
        return matcher.compute(left, right)
    finally:
        # not np.shape: of a ragged list it raised numpy's error over the TypeError above
        shape: tuple[int, ...] = left.shape if isinstance(left, np.ndarray) else ()
        if len(shape) >= 2 and shape[0] * shape[1] > KEEP_MATCHER_MAX_PIXELS:
            release_thread_matcher()  # do not hold a huge pair's buffers


def to_opencv_disparity(disparity: Any, *, min_disparity: int = 0) -> np.ndarray:
    """A float disparity map (NaN for holes) in OpenCV's StereoBM/StereoSGBM format.

    Returns int16 disparity x 16, rounded to the nearest sixteenth (half away from zero), with
    holes (NaN) set to OpenCV's invalid value ``(min_disparity - 1) * 16``. Raises ValueError
    when a finite disparity, so rounded, does not fit: at 2048 px or more, or below
    ``min_disparity`` (which OpenCV's readers, and :func:`stereodepth.from_opencv_disparity`,
    would take for a hole; -0.03 px rounds to 0 and is taken with ``min_disparity=0``); when
    the invalid value or the least disparity (``min_disparity`` outside [-2047, 2047]) does
    not fit in int16; or for a ``disparity`` whose shape is not
    (H, W) or (N, H, W), as every disparity map here (TypeError for one that is not of floats,
    or is a masked array, whose mask would be ignored).
    """
    arr = check.disparity_array("disparity", disparity)
    if arr.dtype.kind != "f":
        raise TypeError(f"disparity must be a float array (NaN for holes), got dtype {arr.dtype}")
    if arr.ndim not in (2, 3):  # from_opencv_disparity takes these only
        raise ValueError(f"disparity must have shape (H, W) or (N, H, W), got {arr.shape}")
    md = check.integer("min_disparity", min_disparity)
    invalid = (md - 1) * 16
    info = np.iinfo(np.int16)
    if not (info.min <= invalid and md * 16 <= info.max):  # [-2047, 2047]
        raise ValueError(
            f"min_disparity must be in [-2047, 2047] (OpenCV's invalid value (min_disparity - 1)"
            f" * 16 and its least disparity min_disparity * 16 must fit in int16), got {md}"
        )
    if np.isinf(arr).any():
        raise ValueError("disparity must be finite or NaN (holes), got an infinite value")
    finite = np.isfinite(arr)
    with np.errstate(over="ignore", invalid="ignore"):  # beyond 1.1e307 px: inf, refused below
        scaled = np.where(finite, arr.astype(np.float64) * 16.0, 0.0)
        # Half away from zero, exactly: trunc(x + 0.5) rounded x + 0.5 first, so that
        # 0.49999999999999994 became 1. (inf - inf is NaN: inf stays inf.)
        whole = np.trunc(scaled)
        fixed = whole + np.copysign(np.abs(scaled - whole) >= 0.5, scaled)
    if finite.any():
        # The messages show the value given ("below 2048 px, got 2048.0" was said of
        # 2047.97, which rounds to 2048 px in sixteenths) and its rounding.
        lo, hi = float(fixed[finite].min()), float(fixed[finite].max())
        if hi > info.max:
            given = float(arr[finite].max())
            raise ValueError(
                f"disparity must be below 2048 px to fit OpenCV's int16 x16 format, got "
                f"{given!r}" + (f" ({hi / 16} px in sixteenths)" if given != hi / 16 else "")
            )
        if lo < md * 16:
            # OpenCV reads every value below min_disparity * 16 as a hole: such a disparity
            # would come back as one, silently.
            given = float(arr[finite].min())
            raise ValueError(
                f"disparity must be >= min_disparity ({md}) px or NaN: OpenCV's format reads "
                f"anything below min_disparity * 16 as a hole, got {given!r} px"
                + (f" ({lo / 16} px in sixteenths)" if given != lo / 16 else "")
            )
    return np.where(finite, fixed, invalid).astype(np.int16)
