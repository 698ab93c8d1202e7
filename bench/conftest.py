"""Shared benchmark plumbing: every benchmark records which implementation it times in
``benchmark.extra_info["impl"]``; at the end, each group's medians are printed as ratios to
stereodepth's own, so one run gives the comparison on this (noisy, shared) machine."""

from __future__ import annotations

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
    for group, items in groups:
        ours = [b for b in items if b["extra_info"].get("impl") == "stereodepth"]
        ref = ours[0]["median"] if ours else None
        tr.write_line(f"{group}")
        for b in sorted(items, key=lambda b: b["median"]):
            label = b["extra_info"].get("impl", b["name"])
            ratio = f"{b['median'] / ref:8.2f}x" if ref else "        -"
            tr.write_line(f"    {label:<40} median {b['median'] * 1e3:10.3f} ms  {ratio}")


@pytest.fixture
def impl(benchmark: Any) -> Any:
    """Names the implementation a benchmark times: ``impl("stereodepth")``."""

    def name(label: str) -> None:
        benchmark.extra_info["impl"] = label

    return name
