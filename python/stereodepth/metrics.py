"""Accuracy of a disparity map against ground truth: density, bad-pixel rates, mean errors.

The convention is the one of the Middlebury stereo evaluation, also used by our shared scenes
(``shared/data/stereo/README.md``):

- The *evaluated* pixels are those whose ground truth is finite and, when a mask is given,
  where the mask is true (typically the non-occluded pixels).
- Ground truth marks unknown pixels with NaN or inf (Middlebury's PFM files write inf).
  The datasets' integer encodings use 0 for "unknown" (KITTI's uint16 PNG, Middlebury's
  2001-2006 PNGs): decode those to NaN first, since a float 0 is a valid disparity (a point at
  infinity). Neither dataset has negative disparities, and no convention uses a negative
  value as a marker we could honour silently, so a negative evaluated ground truth is an error
  (ValueError naming ``gt``, the value and its pixel) unless the matcher searched negative
  disparities (``min_disparity < 0``: a rig whose principal points differ, where negative
  true disparities are real).
- An evaluated pixel has an *estimate* when its disparity is finite; NaN (or any non-finite
  value) is a hole. OpenCV's int16 output (disparity x 16) is read with the matcher's
  ``min_disparity``: raw values below ``min_disparity * 16`` are holes (OpenCV writes
  ``(minDisparity - 1) * 16``), the rest are disparities, negative ones included.
- ``bad_t`` is the fraction of evaluated pixels whose estimate is missing or off by more than
  ``t`` pixels: holes count as bad. ``bad_t_est`` is the same fraction among the evaluated
  pixels that have an estimate (holes left out).
- ``d1`` is KITTI's outlier rate (Geiger, Lenz and Urtasun, CVPR 2012; the stereo 2015
  devkit's D1): the fraction of evaluated pixels whose estimate is missing or off by more
  than 3 px *and* by more than 5 % of the true disparity (``|d - g| > 3`` and
  ``|d - g| / |g| > 0.05``). Holes count as outliers here, as in ``bad_t`` (KITTI's devkit
  fills them by background interpolation first, so its D1 of a map with holes differs);
  ``d1_est`` is the same fraction among the pixels that have an estimate.
- ``density`` is the fraction of evaluated pixels with an estimate; ``avgerr`` and ``rms`` are
  the mean and root-mean-square absolute error over those pixels.

Fractions are in [0, 1] (multiply by 100 for percent). Errors are computed in float64; an
error beyond a double's range (an estimate of -1e308 against 1e308) is ``inf``, and so are
``avgerr`` and ``rms`` then.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from . import _validate as check
from .depth import check_min_disparity, from_opencv_disparity

__all__ = [
    "BAD_THRESHOLDS_PX",
    "D1_THRESHOLD_PX",
    "D1_THRESHOLD_RELATIVE",
    "DisparityMetrics",
    "evaluate",
    "negative_ground_truth",
]

#: The error thresholds of the bad-pixel rates, in pixels.
BAD_THRESHOLDS_PX: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0)
#: KITTI's D1 outlier rule: off by more than 3 px and by more than 5 % of the true disparity.
D1_THRESHOLD_PX = 3.0
D1_THRESHOLD_RELATIVE = 0.05


@dataclass(frozen=True)
class DisparityMetrics:
    """The accuracy of one disparity map; see the module docstring for the convention.

    Attributes
    ----------
    evaluated
        Number of evaluated pixels: finite ground truth, inside the mask when one is given.
    estimated
        Number of evaluated pixels with an estimate (a finite disparity).
    density
        ``estimated / evaluated``.
    bad_0_5, bad_1, bad_2, bad_4
        Fraction of evaluated pixels that are holes or off by more than 0.5, 1, 2 or 4 px.
    bad_0_5_est, bad_1_est, bad_2_est, bad_4_est
        Fraction of estimated pixels off by more than 0.5, 1, 2 or 4 px.
    d1
        KITTI's D1: fraction of evaluated pixels that are holes or off by more than 3 px and
        more than 5 % of the true disparity.
    d1_est
        The same fraction among the estimated pixels (holes left out).
    avgerr
        Mean absolute error in pixels over the estimated pixels.
    rms
        Root-mean-square error in pixels over the estimated pixels.

    Fractions are NaN when there is no pixel to take them over (no evaluated pixel; for the
    ``_est`` rates, ``avgerr`` and ``rms``: no estimated pixel).
    """

    evaluated: int
    estimated: int
    density: float
    bad_0_5: float
    bad_1: float
    bad_2: float
    bad_4: float
    bad_0_5_est: float
    bad_1_est: float
    bad_2_est: float
    bad_4_est: float
    d1: float
    d1_est: float
    avgerr: float
    rms: float

    def as_dict(self) -> dict[str, Any]:
        """The fields as a plain dict (ints and floats), in declaration order."""
        return asdict(self)


def _float_map(name: str, value: Any, what: str) -> np.ndarray:
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be a 2-D floating-point array ({what}), got bool {value!r}")
    try:
        arr = value if isinstance(value, np.ndarray) else np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise TypeError(
            f"{name} must be a 2-D floating-point array ({what}), got {type(value).__name__}"
        ) from exc
    if arr.dtype.kind != "f":
        hint = ""
        if name == "disparity" and arr.dtype == np.int16:
            hint = (
                "; for OpenCV's fixed-point output (x16) pass the matcher's minDisparity as "
                "min_disparity (its holes are the values below min_disparity * 16), or convert "
                "with stereodepth.from_opencv_disparity(raw, min_disparity=...)"
            )
        elif arr.dtype == np.uint16:
            hint = (
                "; KITTI's PNG encoding must be converted first: "
                "d = raw.astype(np.float32) / 256 with d[raw == 0] = np.nan "
                "(stereodepth.io.read_disparity_png16 reads such a file so)"
            )
        elif name == "gt" and arr.dtype == np.uint8:
            hint = (
                "; Middlebury's 2001-2006 PNGs store d * s (s = 16 for tsukuba, 8 for venus, "
                "4 for the 2003 sets, 3 for the third-size 2005/2006 ones) with 0 unknown: "
                "d = raw.astype(np.float32) / s with d[raw == 0] = np.nan"
            )
        raise TypeError(
            f"{name} must be a floating-point array ({what}), got dtype {arr.dtype}{hint}"
        )
    if arr.ndim != 2:
        raise ValueError(f"{name} must have shape (H, W), got {arr.shape}")
    return arr


def negative_ground_truth(gt: np.ndarray, where: np.ndarray | None = None) -> str | None:
    """Why ``gt`` (a float disparity map) is not ground truth a harness should score, or
    None: the first negative finite value (within ``where``, a bool array of its shape, when
    given), its pixel and how many there are. See the module docstring for the rule."""
    with np.errstate(invalid="ignore"):
        negative = np.isfinite(gt) & (gt < 0)
    if where is not None:
        negative &= where
    count = int(np.count_nonzero(negative))
    if count == 0:
        return None
    row, col = (int(i) for i in np.argwhere(negative)[0])
    return (
        f"must be >= 0 where it is finite (KITTI and Middlebury have no negative disparity; "
        f"mark unknown pixels with NaN or inf, and decode KITTI's 0 to NaN), got "
        f"{float(gt[row, col])!r} at row {row}, column {col} ({count} negative pixel"
        f"{'s' if count > 1 else ''})"
    )


def evaluate(
    disparity: Any, gt: Any, mask: Any = None, *, min_disparity: int | None = None
) -> DisparityMetrics:
    """Scores an estimated disparity map against the ground truth.

    Parameters
    ----------
    disparity
        (H, W) float16/32/64 disparity of the left image in pixels, NaN where there is no
        estimate (the output of :func:`stereodepth.block_match`), or OpenCV's int16 (x16)
        output as ``StereoBM`` / ``StereoSGBM`` return it, with ``min_disparity``. KITTI's
        uint16 (x256) is rejected: convert it with ``/ 256`` and 0 to NaN.
    gt
        (H, W) floating-point ground-truth disparity; non-finite values (NaN, or inf as in
        Middlebury's PFM files) mark unknown pixels, which are not evaluated. Evaluated values
        must be >= 0 unless ``min_disparity`` is negative (see the module docstring).
    mask
        Optional (H, W) bool array: only pixels where it is true are evaluated (for example
        the non-occluded pixels).
    min_disparity
        The smallest disparity the matcher searched, in pixels; disparities below it are
        holes. int16 input needs it: it is OpenCV's ``minDisparity``, and raw values below
        ``min_disparity * 16`` are holes, as :func:`stereodepth.from_opencv_disparity` decodes
        them (the score must not guess the hole marker, so there is no default here). For
        float input there is no lower limit unless it is given. A negative value also admits
        negative ground truth.

    Returns
    -------
    DisparityMetrics
        Density, bad-pixel rates with and without holes, mean and RMS error.

    Raises TypeError for a disparity that is neither float nor int16, a non-float ground
    truth, a non-bool mask, a masked array (``numpy.ma``: its mask would be ignored; give NaN
    or ``mask``) or a non-integer ``min_disparity``, and ValueError for shapes that
    are not (H, W) or do not match, or for a negative evaluated ground truth (without a
    negative ``min_disparity``).
    """
    md = None if min_disparity is None else check_min_disparity(min_disparity)
    check.not_masked("disparity", disparity)
    check.not_masked("gt", gt)
    disparity, gt = (
        check.native_order(a) if isinstance(a, np.ndarray) else a for a in (disparity, gt)
    )
    if md is not None and isinstance(disparity, np.ndarray) and disparity.dtype == np.int16:
        disparity = from_opencv_disparity(disparity, min_disparity=md)
    d = _float_map("disparity", disparity, "pixels, NaN for holes")
    if md is not None:
        # A min_disparity beyond the dtype's range (-70000 against float16) rounds to -inf or
        # inf in the comparison, which keeps its meaning; numpy warned "overflow in cast".
        with np.errstate(invalid="ignore", over="ignore"):
            d = np.where(d < md, np.nan, d)
    g = _float_map("gt", gt, "pixels, NaN where unknown")
    if g.shape != d.shape:
        raise ValueError(f"gt must have the shape of disparity {d.shape}, got {g.shape}")
    evaluated = np.isfinite(g)
    if mask is not None:
        m = check.array("mask", mask)
        if m.dtype != np.bool_:
            raise TypeError(f"mask must be a bool array, got dtype {m.dtype}")
        if m.shape != d.shape:
            raise ValueError(f"mask must have the shape of disparity {d.shape}, got {m.shape}")
        evaluated &= m
    if md is None or md >= 0:
        problem = negative_ground_truth(g, evaluated)
        if problem is not None:
            raise ValueError(
                f"gt {problem}; pass min_disparity < 0 if the matcher searched negative disparities"
            )

    n_eval = int(np.count_nonzero(evaluated))
    est = d[evaluated].astype(np.float64)
    ok = np.isfinite(est)
    truth = g[evaluated][ok].astype(np.float64)
    with np.errstate(over="ignore"):  # an error beyond a double's range is inf
        err = np.abs(est[ok] - truth)
    # KITTI's devkit: d_err > tau_1 and d_err / |d_gt| > tau_2 (a true disparity of 0 with
    # any error is relative error inf; 0 / 0 is no outlier, as 0 is not > 3 anyway).
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        outliers = int(
            np.count_nonzero(
                (err > D1_THRESHOLD_PX) & (err / np.abs(truth) > D1_THRESHOLD_RELATIVE)
            )
        )
    n_est = int(err.size)
    # The mean and RMS scaled by the largest error, so that neither the sum nor the squares
    # overflow where the result fits (errors of 1e200 px squared to inf with a warning).
    top = float(err.max()) if n_est else 0.0
    if 0.0 < top < math.inf:
        scaled = err / top
        avgerr = top * float(scaled.mean())
        rms = top * math.sqrt(float(np.mean(scaled * scaled)))
    else:  # no estimate (NaN below), every error 0, or an infinite error (inf)
        avgerr = rms = top
    nan = float("nan")

    def frac(count: int, total: int) -> float:
        return count / total if total else nan

    bad: dict[str, float] = {}
    for t in BAD_THRESHOLDS_PX:
        key = "bad_" + f"{t:g}".replace(".", "_")
        wrong = int(np.count_nonzero(err > t))
        bad[key] = frac(wrong + n_eval - n_est, n_eval)
        bad[key + "_est"] = frac(wrong, n_est)
    return DisparityMetrics(
        evaluated=n_eval,
        estimated=n_est,
        density=frac(n_est, n_eval),
        bad_0_5=bad["bad_0_5"],
        bad_1=bad["bad_1"],
        bad_2=bad["bad_2"],
        bad_4=bad["bad_4"],
        bad_0_5_est=bad["bad_0_5_est"],
        bad_1_est=bad["bad_1_est"],
        bad_2_est=bad["bad_2_est"],
        bad_4_est=bad["bad_4_est"],
        d1=frac(outliers + n_eval - n_est, n_eval),
        d1_est=frac(outliers, n_est),
        avgerr=avgerr if n_est else nan,
        rms=rms if n_est else nan,
    )
