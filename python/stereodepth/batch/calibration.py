"""Which calibration and number of disparities each pair uses. The files themselves are read by
:mod:`stereodepth.calib`.

Precedence
    A pair's rig (focal length, baseline, doffs, principal point) comes whole from the first
    of: (1) ``--focal-px`` and ``--baseline-mm`` on the command line (with ``--doffs-px``,
    ``--cx-px``, ``--cy-px``); (2) ``--calib FILE``; (3) the pair's own file: ``calib.txt``
    in its folder (Middlebury) or ``calib/<frame>.txt`` of its KITTI set. The number of
    disparities is ``--num-disparities``, else ``ndisp`` of the file the rig came from (a
    Middlebury ``calib.txt``; KITTI files have none). A pair's own file that a higher source
    replaces is not read; each pair's record names the source used and the file not used.

Raw pairs
    A ``--calib`` file that is not a Middlebury or KITTI calibration is the calibration of a
    raw pair (OpenCV FileStorage YAML/XML/JSON, Kalibr, ROS camera_info with ``--calib-right``),
    and every pair is rectified before matching, by the rule of ``stereodepth match``
    (:mod:`stereodepth._calib_rule`): the rectifier is built once (:class:`BatchRectifier`;
    on Dask the calibration travels and each worker process builds it once), and the rig is
    the rectifier's, so the depth and points are in the rectified left camera's frame.
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..calib import Calibration, StereoCalibration, read_calibration
from ..matching import MAX_NUM_DISPARITIES
from .job import Pair, UsageError

#: The source named in records for a rig given on the command line.
COMMAND_LINE = "--focal-px/--baseline-mm"


def calibration_note(pairs: Sequence[Pair]) -> str | None:
    """One line saying which calibration the pairs use when a command-line option replaced
    the pairs' own files, else None."""
    unused = [p for p in pairs if p.calibration is not None and p.calib_file_unused]
    if not unused:
        return None
    first = unused[0]
    source = first.calibration.source if first.calibration is not None else ""
    n = len(unused)
    whose = "pairs' own calibration files" if n != 1 else "pair's own calibration file"
    return f"calibration: {source} for every pair; {n} {whose} (e.g. {first.calib_file}) not used"


def resolve_calibration(
    pairs: Sequence[Pair],
    *,
    given: Calibration | None = None,
    calib_file: Path | None = None,
    num_disparities: int | None = None,
    calib_rig: Calibration | None = None,
) -> list[Pair]:
    """Each pair with its calibration and number of disparities, or the problem that stops it,
    by the precedence of :mod:`stereodepth.batch.calibration`: ``given`` (the command line)
    wins over ``calib_file`` (``--calib``) which wins over each pair's own file.
    ``calib_rig`` is the rig of a raw ``calib_file`` (its rectified rig, from
    :func:`raw_rectification`), used instead of reading the file.

    Raises UsageError when no pair has a calibration or a number of disparities, so a
    forgotten option is one clear error (naming where the calibration came from) rather than
    a failure per pair."""
    from .._calib_rule import rig_range_problem

    def out_of_range(calib: Calibration) -> str | None:
        flags = calib.source == COMMAND_LINE
        why = rig_range_problem(calib.focal_px, calib.baseline_m, calib.doffs_px, flags=flags)
        if why is None or flags:
            return why
        return f"{calib.source}: {why}"

    shared = given if given is not None else calib_rig
    if shared is not None and (why := out_of_range(shared)) is not None:
        raise UsageError(why)
    # A KITTI --calib holds four cameras: each pair reads those of its folders (a job may
    # hold grey image_0/image_1 pairs and colour image_2/image_3 ones).
    by_cams: dict[tuple[int, int] | None, Calibration] = {}
    if shared is None and calib_file is not None:
        for cams in dict.fromkeys([p.kitti_cams for p in pairs] or [None]):
            try:
                read = read_calibration(calib_file, cams)
            except (OSError, ValueError) as exc:
                raise UsageError(f"--calib: {exc}") from exc
            by_cams[cams] = replace(read, source=f"--calib {calib_file}")
            if (why := out_of_range(by_cams[cams])) is not None:
                raise UsageError(why)
    out = []
    cache: dict[tuple[Path, tuple[int, int] | None], Calibration | str] = {}
    for p in pairs:
        calib: Calibration | None = shared if not by_cams else by_cams[p.kitti_cams]
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
                problem = problem or out_of_range(found)
        if calib is None:
            problem = problem or (
                "no calibration: give --focal-px and --baseline-mm, or --calib FILE, or put a "
                "calib.txt beside the images"
            )
        nd = num_disparities
        if nd is None and calib is not None:
            nd = calib.num_disparities
            if nd is None:
                problem = problem or f"no --num-disparities, and {calib.source} has no ndisp"
            elif nd > MAX_NUM_DISPARITIES:  # the matcher's error did not say where it came from
                problem = problem or (
                    f"{calib.source}: ndisp={nd} is more than the matchers search "
                    f"({MAX_NUM_DISPARITIES}): give --num-disparities"
                )
        out.append(
            replace(
                p,
                calibration=calib,
                num_disparities=nd,
                problem=problem,
                calib_file_unused=(shared is not None or bool(by_cams))
                and p.calib_file is not None,
            )
        )
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
        raise UsageError(_ndisp_required(out, given, calib_file))
    return out


def _ndisp_required(
    pairs: Sequence[Pair], given: Calibration | None, calib_file: Path | None
) -> str:
    """The true reason why no pair has a number of disparities."""
    head = "--num-disparities is required"
    if given is not None:
        own = [p.calib_file for p in pairs if p.calib_file is not None]
        if own:
            return (
                f"{head} with --focal-px and --baseline-mm: they replace the pairs' own "
                f"calibration files ({len(own)} found, e.g. {own[0]}), whose ndisp is then "
                "not used"
            )
        return f"{head} with --focal-px and --baseline-mm"
    if calib_file is not None:
        return f"{head}: --calib {calib_file} has no ndisp"
    files = sorted({str(p.calibration.source) for p in pairs if p.calibration is not None})
    kitti = any(p.kitti_cams for p in pairs if p.calibration is not None)
    return f"{head}: the pairs' calibration files have no ndisp (e.g. {files[0]})" + (
        "; KITTI calibration files never have one" if kitti else ""
    )


#: Rectifiers built in this process, by (calibration digest, threads): each worker process of
#: a Dask job builds a job's maps once, not once per pair. A few entries at most.
_RECTIFIERS: dict[tuple[str, int], Any] = {}
_RECTIFIERS_LOCK = threading.RLock()
_RECTIFIERS_KEPT = 4


def _digest(stereo: StereoCalibration, alpha: float | None = None) -> str:
    """A fingerprint of everything the rectification depends on (``--alpha`` included)."""
    h = hashlib.sha256()
    h.update(f"{stereo.distortion_model}|{tuple(stereo.image_size)}|{alpha!r}".encode())
    for name in ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q"):
        value = getattr(stereo, name, None)
        h.update(name.encode())
        if value is not None:
            h.update(np.ascontiguousarray(value, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


class BatchRectifier:
    """Rectifies every pair of a job whose ``--calib`` file is a raw calibration, by the rule
    of ``stereodepth match`` (:mod:`stereodepth._calib_rule`).

    It holds the calibration (``stereo``, a :class:`stereodepth.calib.StereoCalibration`),
    which is what travels to Dask workers (a few hundred bytes), and builds the
    :class:`stereodepth.StereoRectifier` from it once per process and thread count: its maps
    are not rebuilt for each pair. ``source`` names the file(s) in records."""

    def __init__(
        self,
        stereo: StereoCalibration,
        source: str,
        rectifier: Any = None,
        *,
        alpha: float | None = None,
    ) -> None:
        self.stereo = stereo
        self.source = source
        self.alpha = alpha
        self.digest = _digest(stereo, alpha)
        w, h = (int(v) for v in stereo.image_size)
        self.image_size = (w, h)
        if rectifier is not None:
            self._keep(rectifier.threads, rectifier)

    def __getstate__(self) -> dict[str, Any]:
        return {"stereo": self.stereo, "source": self.source, "alpha": self.alpha}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["stereo"], state["source"], alpha=state["alpha"])  # type: ignore[misc]

    def __eq__(self, other: object) -> bool:
        return isinstance(other, BatchRectifier) and (self.digest, self.source) == (
            other.digest,
            other.source,
        )

    def __hash__(self) -> int:
        return hash((self.digest, self.source))

    def __repr__(self) -> str:
        return f"BatchRectifier({self.source!r}, {self.image_size[0]}x{self.image_size[1]} px)"

    def _keep(self, threads: int, rectifier: Any) -> None:
        with _RECTIFIERS_LOCK:
            while len(_RECTIFIERS) >= _RECTIFIERS_KEPT:
                _RECTIFIERS.pop(next(iter(_RECTIFIERS)))
            _RECTIFIERS[(self.digest, threads)] = rectifier

    def rectifier(self, threads: int | None = None) -> Any:
        """This process's :class:`stereodepth.StereoRectifier` of the calibration with
        ``threads`` (None or 0: every core), built on first use."""
        from .. import _calib_rule
        from .. import _validate as check

        n = check.threads(threads)
        # Built under the lock: threads of one worker that start together build it once.
        with _RECTIFIERS_LOCK:
            found = _RECTIFIERS.get((self.digest, n))
            if found is None:
                found = _calib_rule.raw_rectifier(
                    self.stereo, self.source, threads=n, alpha=self.alpha
                )
                self._keep(n, found)
        return found

    def vertical(self, threads: int | None = None) -> bool:
        """Whether the rectified baseline is along y (the pair is then matched transposed)."""
        return bool(self.rectifier(threads).vertical)

    def rectify(
        self, left: np.ndarray, right: np.ndarray, threads: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The rectified pair. Raises ValueError when the images are not of the calibration's
        size."""
        w, h = self.image_size
        if left.shape[:2] != (h, w):
            raise ValueError(
                f"the pair is {left.shape[1]}x{left.shape[0]} px, and --calib {self.source} is "
                f"the calibration of {w}x{h} px images"
            )
        rectified: tuple[np.ndarray, np.ndarray] = self.rectifier(threads).rectify(left, right)
        return rectified

    def as_dict(self) -> dict[str, Any]:
        """What records and the report say: the calibration, its digest, the sizes."""
        return {
            "calibration": self.source,
            "digest": self.digest,
            "alpha": self.alpha,
            "raw_size": list(self.image_size),
            "rectified_size": list(self.image_size),
        }


def raw_rectification(
    calib: str,
    *,
    calib_right: str | None = None,
    translation_unit: str | None = None,
    no_rectify: bool = False,
    write_rectified: bool = False,
    alpha: float | None = None,
    distortion_model: str | None = None,
    image_size: tuple[int, int] | None = None,
    threads: int | None = None,
) -> tuple[BatchRectifier, Calibration] | None:
    """For a raw ``--calib`` file: the job's :class:`BatchRectifier` (its rectifier built now,
    so that a calibration that cannot rectify stops the job before the first pair) and the
    rectified rig every pair's depth uses (the rectified left camera's: focal length,
    baseline, doffs, principal point of P1). None for a Middlebury or KITTI file (a rectified
    pair: :func:`resolve_calibration` reads it). Raises UsageError in the flags' names; the
    rule is ``stereodepth match``'s (:mod:`stereodepth._calib_rule`)."""
    from .. import _calib_rule as rule

    try:
        stereo = rule.raw_calibration(
            calib,
            calib_right=calib_right,
            translation_unit=translation_unit,
            no_rectify=no_rectify,
            write_rectified=write_rectified,
            alpha=alpha,
            distortion_model=distortion_model,
            image_size=image_size,
        )
        if stereo is None:
            return None
        source = rule.calibration_source(calib, calib_right)
        rectifier = rule.raw_rectifier(stereo, source, threads=threads, alpha=alpha)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    rig = rule.rectified_rig(rectifier)
    rectified = Calibration(
        focal_px=rig["focal_px"],
        baseline_m=rig["baseline_m"],
        doffs_px=rig["doffs_px"],
        cx_px=rig["cx_px"],
        cy_px=rig["cy_px"],
        source=f"--calib {source} (rectified)",
    )
    return BatchRectifier(stereo, source, rectifier, alpha=alpha), rectified
