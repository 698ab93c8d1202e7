"""Ctrl-C (SIGINT) during a long native match stops it within a few rows.

Each case runs in a child process, which sends SIGINT to itself from a timer thread while its
main thread is inside a matcher's ``compute``. The child first times an uninterrupted call
(T, after a first call that allocates), then interrupts an identical call T/4 after it
starts: with the stop it answers within a few milliseconds, without it only when the call
ends, 3T/4 later. The thresholds are set from T, so a slower machine does not change the
verdict.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to oneself is POSIX")

CHILD = textwrap.dedent(
    """
    import json, os, signal, sys, threading, time
    import numpy as np
    import stereodepth as sd

    kind, rows, cols, nd, paths, mode = sys.argv[1:7]
    rows, cols, nd, paths = int(rows), int(cols), int(nd), int(paths)
    rng = np.random.default_rng(7)
    left = rng.integers(0, 256, (rows, cols), dtype=np.uint8)
    right = np.roll(left, -9, axis=1)

    if kind == "sgm-bands":  # paths 8's column bands, which meet at every row
        sd._core._sgm_column_bands_for_tests(True)

    def matcher():
        if kind == "bm":
            return sd.StereoMatcher(num_disparities=nd, threads=2)
        return sd.SemiGlobalMatcher(
            num_disparities=nd, paths=paths, threads=2, max_memory_mb=8000
        )

    m = matcher()
    reference = m.compute(left, right)  # the first call also allocates the scratch
    t0 = time.monotonic()
    m.compute(left, right)
    full = time.monotonic() - t0
    report = {"full": full}
    handled = []
    if mode == "own-handler":
        signal.signal(signal.SIGINT, lambda *a: handled.append(time.monotonic()))

    def kick(delay):
        time.sleep(delay)
        report["sent"] = time.monotonic()
        os.kill(os.getpid(), signal.SIGINT)

    done = threading.Event()

    def run():
        t = time.monotonic()
        try:
            out = m.compute(left, right)
            report["result"] = "finished"
            report["same"] = bool(np.array_equal(out, reference, equal_nan=True))
        except KeyboardInterrupt:
            report["result"] = "interrupted"
        report["ended"] = time.monotonic()
        done.set()

    threading.Thread(target=kick, args=(full / 4,), daemon=True).start()
    if mode == "other-thread":
        worker = threading.Thread(target=run)
        worker.start()
        try:
            worker.join()
        except KeyboardInterrupt:
            report["main"] = "interrupted"
            # Not join() alone: CPython 3.11's Thread.join, interrupted, marks the thread as
            # stopped (bpo-45274's clean-up), and a second join() returned at once, the
            # report read while the worker was still writing it.
            done.wait()
            worker.join()
    else:
        try:
            run()
        except KeyboardInterrupt:  # arrived after the call had ended
            report["result"] = "late"
    report["handled"] = len(handled)
    # The matcher works as before after a stopped call.
    crop = m.compute(left[:48], right[:48])
    report["after"] = bool(np.array_equal(crop, matcher().compute(left[:48], right[:48]),
                                          equal_nan=True))
    print(json.dumps(report))
    """
)

# Sizes for an uninterrupted call of roughly 0.5-2 s on two cores.
CASES = {
    "block-matching": ("bm", 1500, 2000, 2048, 0),
    "semi-global-3": ("sgm", 1500, 2000, 1024, 3),
    "semi-global-8": ("sgm", 720, 1280, 512, 8),
    "semi-global-8-bands": ("sgm-bands", 720, 1280, 512, 8),
}


def run_child(case: str, mode: str) -> dict:
    args = [str(a) for a in CASES[case]] + [mode]
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, *args], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("case", sorted(CASES))
def test_ctrl_c_stops_a_long_match_within_rows(case: str) -> None:
    r = run_child(case, "main")
    assert r["result"] == "interrupted", r
    # Without the stop the call would run about 3/4 of `full` more after the signal.
    assert r["ended"] - r["sent"] < r["full"] / 8, r
    assert r["after"], r


def test_ctrl_c_leaves_a_call_on_another_thread_alone() -> None:
    # Python raises KeyboardInterrupt in the main thread only; the worker's call goes on.
    r = run_child("semi-global-3", "other-thread")
    assert r.get("main") == "interrupted", r
    assert r["result"] == "finished" and r["same"], r
    assert r["after"], r


def test_ctrl_c_leaves_a_call_alone_under_the_programs_own_handler() -> None:
    # A program with its own SIGINT handler decides what Ctrl-C means: the call ends normally
    # and the handler runs.
    r = run_child("block-matching", "own-handler")
    assert r["result"] == "finished" and r["same"], r
    assert r["handled"] == 1, r
    assert r["after"], r
