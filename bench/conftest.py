"""Shared benchmark plumbing: every benchmark records which implementation it times in
``benchmark.extra_info["impl"]``; at the end, each group's medians are printed as ratios to
stereodepth's own, so one run gives the comparison on this (noisy, shared) machine.

Optional extras a benchmark may record: ``extra_info["pixel_disparities"]`` (W x H x D of a
stereo matcher) adds the time per pixel-disparity. When an implementation label appears in
several groups beside stereodepth, the summary ends with the median over those groups of its
time relative to stereodepth's."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable
from statistics import median
from typing import Any

import pytest


@pytest.hookimpl(trylast=True)
def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: Any) -> None:
    session = getattr(config, "_benchmarksession", None)
    groups = getattr(session, "groups", None)
    if not groups:
        return
    tr = terminalreporter
    tr.write_sep("=", "median time relative to stereodepth (lower is faster)")
    across: dict[str, list[float]] = defaultdict(list)
    for group, items in groups:
        ours = [b for b in items if b["extra_info"].get("impl") == "stereodepth"]
        ref = ours[0]["median"] if ours else None
        tr.write_line(f"{group}")
        for b in sorted(items, key=lambda b: b["median"]):
            label = b["extra_info"].get("impl", b["name"])
            ratio = f"{b['median'] / ref:8.2f}x" if ref else "        -"
            work = b["extra_info"].get("pixel_disparities")
            per = f"  {b['median'] * 1e9 / work:6.3f} ns/(px*d)" if work else ""
            tr.write_line(f"    {label:<40} median {b['median'] * 1e3:10.3f} ms  {ratio}{per}")
            if ref and label != "stereodepth":
                across[label].append(b["median"] / ref)
    shared = {label: r for label, r in across.items() if len(r) > 1}
    if shared:
        tr.write_sep("-", "median over groups, relative to stereodepth")
        for label, ratios in sorted(shared.items()):
            m = median(ratios)
            tr.write_line(
                f"    {label:<40} {m:8.2f}x over {len(ratios)} groups "
                f"(stereodepth / {label}: {1 / m:.3f})"
            )


@pytest.fixture
def impl(benchmark: Any) -> Any:
    """Names the implementation a benchmark times: ``impl("stereodepth")``."""

    def name(label: str) -> None:
        benchmark.extra_info["impl"] = label

    return name


def alternate_calls(
    first: Callable[[], Any], second: Callable[[], Any], rounds: int
) -> tuple[list[float], list[float]]:
    """Each call's times in seconds over `rounds` rounds of two calls, their order swapped
    every round, so that each call follows the other as often as itself: a call right after
    another matcher's finds its own buffers out of the cache (about 8 % slower on Tsukuba),
    whichever matcher it is. The ratio of two matchers is then read per round, so that both
    see the same moments of a machine whose speed drifts."""
    took: tuple[list[float], list[float]] = ([], [])
    for i in range(rounds):
        for k in (0, 1) if i % 2 == 0 else (1, 0):
            t0 = time.perf_counter()
            (first, second)[k]()
            took[k].append(time.perf_counter() - t0)
    return took


@pytest.fixture
def alternate() -> Callable[..., tuple[list[float], list[float]]]:
    """:func:`alternate_calls`, for the interleaved speed comparisons."""
    return alternate_calls
