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
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from ..calib import Calibration, read_calibration
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
    return (
        f"calibration: {source} for every pair; {n} pair{'s' if n != 1 else ''}' own "
        f"calibration file{'s' if n != 1 else ''} (e.g. {first.calib_file}) not used"
    )


def resolve_calibration(
    pairs: Sequence[Pair],
    *,
    given: Calibration | None = None,
    calib_file: Path | None = None,
    num_disparities: int | None = None,
) -> list[Pair]:
    """Each pair with its calibration and number of disparities, or the problem that stops it,
    by the precedence of :mod:`stereodepth.batch.calibration`: ``given`` (the command line)
    wins over ``calib_file`` (``--calib``) which wins over each pair's own file.

    Raises UsageError when no pair has a calibration or a number of disparities, so a
    forgotten option is one clear error (naming where the calibration came from) rather than
    a failure per pair."""
    shared = given
    if shared is None and calib_file is not None:
        try:
            shared = read_calibration(calib_file, pairs[0].kitti_cams if pairs else None)
        except (OSError, ValueError) as exc:
            raise UsageError(f"--calib: {exc}") from exc
        shared = replace(shared, source=f"--calib {calib_file}")
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
            if nd is None:
                problem = problem or f"no --num-disparities, and {calib.source} has no ndisp"
        out.append(
            replace(
                p,
                calibration=calib,
                num_disparities=nd,
                problem=problem,
                calib_file_unused=shared is not None and p.calib_file is not None,
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
