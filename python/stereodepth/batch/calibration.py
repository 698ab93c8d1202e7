"""Which calibration and number of disparities each pair uses. The files themselves are read by
:mod:`stereodepth.calib`."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..calib import Calibration, read_calibration
from .job import Pair, UsageError


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
