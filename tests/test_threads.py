"""The default thread count: the CPUs the process may use, lowered to its control group's CPU
quota (a container started with ``--cpus 2`` on a 64-core host must not run 64 threads: the
semi-global matcher's 8-path passes, which meet after every row, ran 8 to 20 times slower
with more threads than cores). ``_cgroup_cpu_limit`` reads the files below a root folder, so
the tests lay out fake ``/proc/self/cgroup`` and ``/sys/fs/cgroup`` trees (cgroup v2 and v1)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import _core


def child_exit_code(pid: int, timeout: float, hung: str) -> int:
    """The exit code of forked child `pid`; the test fails with `hung` (the child killed) when
    it has not exited within `timeout` seconds."""
    import time

    deadline = time.monotonic() + timeout
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(status)
        if time.monotonic() > deadline:
            os.kill(pid, 9)
            os.waitpid(pid, 0)
            pytest.fail(hung)
        time.sleep(0.01)


def run_python(code: str) -> subprocess.CompletedProcess[str]:
    """``code`` run by a fresh interpreter that imports this stereodepth (the test's sys.path),
    its output captured; subprocess.TimeoutExpired after 60 s."""
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )


def tree(root: Path, files: dict[str, str]) -> str:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return str(root)


@pytest.mark.parametrize(
    ("files", "cpus"),
    [
        # cgroup v2: the process's group and its parents; the smallest quota wins, rounded up.
        (
            {
                "proc/self/cgroup": "0::/app/job\n",
                "sys/fs/cgroup/app/job/cpu.max": "200000 100000\n",
            },
            2,
        ),
        (
            {
                "proc/self/cgroup": "0::/app/job\n",
                "sys/fs/cgroup/app/job/cpu.max": "150000 100000\n",
            },
            2,
        ),
        (
            {
                "proc/self/cgroup": "0::/app/job\n",
                "sys/fs/cgroup/app/job/cpu.max": "50000 100000\n",
            },
            1,
        ),
        (
            {
                "proc/self/cgroup": "0::/app/job\n",
                "sys/fs/cgroup/app/job/cpu.max": "max 100000\n",
                "sys/fs/cgroup/app/cpu.max": "300000 100000\n",
                "sys/fs/cgroup/cpu.max": "800000 100000\n",
            },
            3,
        ),
        ({"proc/self/cgroup": "0::/\n", "sys/fs/cgroup/cpu.max": "max 100000\n"}, 0),
        ({"proc/self/cgroup": "0::/\n"}, 0),  # no cpu controller file: no limit
        # A container's namespace: its group is "/" and the mount is its own group.
        ({"proc/self/cgroup": "0::/\n", "sys/fs/cgroup/cpu.max": "400000 100000\n"}, 4),
        # cgroup v1, the cpu controller mounted alone or with cpuacct.
        (
            {
                "proc/self/cgroup": "4:memory:/x\n2:cpu,cpuacct:/docker/abc\n1:name=systemd:/\n",
                "sys/fs/cgroup/cpu,cpuacct/docker/abc/cpu.cfs_quota_us": "250000\n",
                "sys/fs/cgroup/cpu,cpuacct/docker/abc/cpu.cfs_period_us": "100000\n",
            },
            3,
        ),
        (
            {
                "proc/self/cgroup": "3:cpu:/\n",
                "sys/fs/cgroup/cpu/cpu.cfs_quota_us": "-1\n",
                "sys/fs/cgroup/cpu/cpu.cfs_period_us": "100000\n",
            },
            0,
        ),
        # Unreadable or odd content is no limit, never an error.
        ({"proc/self/cgroup": "0::/\n", "sys/fs/cgroup/cpu.max": "lots 100000\n"}, 0),
        ({"proc/self/cgroup": "0::/\n", "sys/fs/cgroup/cpu.max": "100000 0\n"}, 0),
        ({"proc/self/cgroup": "garbage\n\n::\n"}, 0),
        ({}, 0),
    ],
)
def test_cgroup_cpu_limit(tmp_path: Path, files: dict[str, str], cpus: int) -> None:
    assert _core._cgroup_cpu_limit(tree(tmp_path, files)) == cpus


def test_default_threads_is_the_cpus_this_process_may_use() -> None:
    n = stereodepth.build_info()["default_threads"]
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    quota = _core._cgroup_cpu_limit("/")
    assert n == (min(affinity, quota) if quota else affinity)


@pytest.mark.parametrize("paths", [4, 8])
def test_semi_global_vertical_passes_use_at_most_one_thread_per_cpu(paths: int) -> None:
    # The 8- and 4-path modes meet at every row: more threads than CPUs only wait for each
    # other, so the matcher runs at most default_threads() bands (the memory estimate, which
    # counts what is allocated, says so), with the same output.
    from stereodepth.semi_global import memory_estimate

    cpus = stereodepth.build_info()["default_threads"]
    shape = (40, 640)
    same = memory_estimate(shape, num_disparities=64, paths=paths, threads=cpus)
    assert memory_estimate(shape, num_disparities=64, paths=paths, threads=cpus + 14) == same
    if cpus > 1:
        assert memory_estimate(shape, num_disparities=64, paths=paths, threads=1) < same
    rng = np.random.default_rng(5)
    left = rng.integers(0, 256, shape, dtype=np.uint8)
    right = np.roll(left, -7, axis=1)
    one = stereodepth.semi_global_match(left, right, num_disparities=64, paths=paths, threads=1)
    many = stereodepth.semi_global_match(left, right, num_disparities=64, paths=paths, threads=16)
    np.testing.assert_array_equal(one, many)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_matchers_run_in_a_forked_child() -> None:
    # The kernels keep worker threads between calls; a child forked after they started has
    # none of them (fork copies only the calling thread) and must still match, on several
    # threads, without waiting for workers that do not exist.
    import warnings

    rng = np.random.default_rng(5)
    left = rng.integers(0, 256, size=(96, 80), dtype=np.uint8)
    right = np.roll(left, -4, axis=1)
    sgm = stereodepth.SemiGlobalMatcher(num_disparities=16, threads=2)
    bm = stereodepth.StereoMatcher(num_disparities=16, threads=3)
    want = (sgm.compute(left, right), bm.compute(left, right))
    with warnings.catch_warnings():
        # Python 3.12 warns on fork() in any process with threads (numpy's BLAS has some).
        warnings.simplefilter("ignore", DeprecationWarning)
        pid = os.fork()
    if pid == 0:  # the child: exit code 0 when both agree, never return into pytest
        code = 1
        try:
            for _ in range(3):
                got = (sgm.compute(left, right), bm.compute(left, right))
                pairs = zip(got, want, strict=True)
                if not all(np.array_equal(a, b, equal_nan=True) for a, b in pairs):
                    break
            else:
                code = 0
        finally:
            os._exit(code)
    assert child_exit_code(pid, 60, "the forked child hung in a multi-threaded call") == 0


def test_python_threads_share_the_kernels_workers() -> None:
    # Many Python threads, each asking for more native threads than there are cores, at once:
    # every result equals the one-thread result (the bands of concurrent calls share the kept
    # workers, and each call runs the bands no worker has taken).
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(6)
    pairs = []
    for i in range(6):
        left = rng.integers(0, 256, size=(40 + 7 * i, 70), dtype=np.uint8)
        pairs.append((left, np.roll(left, -3, axis=1)))
    makers = [
        lambda t: stereodepth.SemiGlobalMatcher(num_disparities=16, threads=t),
        lambda t: stereodepth.SemiGlobalMatcher(num_disparities=16, paths=8, threads=t),
        lambda t: stereodepth.StereoMatcher(num_disparities=16, threads=t),
    ]
    want = [[make(1).compute(a, b) for a, b in pairs] for make in makers]

    def job(k: int) -> bool:
        make = makers[k % len(makers)]
        m = make(4)
        return all(
            np.array_equal(m.compute(a, b), w, equal_nan=True)
            for (a, b), w in zip(pairs, want[k % len(makers)], strict=True)
        )

    with ThreadPoolExecutor(max_workers=8) as ex:
        assert all(ex.map(job, range(24)))


_IDLE_AFTER_CALLS = """
import time
import numpy as np
import stereodepth

rng = np.random.default_rng(8)
left = rng.integers(0, 256, size=(300, 200), dtype=np.uint8)
right = np.roll(left, -3, axis=1)
for make in (
    lambda: stereodepth.StereoMatcher(num_disparities=32, threads=4),
    lambda: stereodepth.SemiGlobalMatcher(num_disparities=32, threads=4),
    lambda: stereodepth.SemiGlobalMatcher(num_disparities=32, paths=8, threads=4),
):
    make().compute(left, right)
time.sleep(0.05)  # the kept workers' spin ends (0.2 ms)
cpu, wall = time.process_time(), time.monotonic()
time.sleep(0.5)
print(time.process_time() - cpu, time.monotonic() - wall)
"""


def test_kept_workers_go_quiet_after_a_call() -> None:
    # The pool's idle workers (and a caller waiting for its bands) spin a fraction of a
    # millisecond before they sleep, so that the next parallel step finds them awake; then
    # they sleep: half a second after the calls, the process uses (almost) no CPU. A spin
    # that did not end would use a CPU for the whole half second.
    r = run_python(_IDLE_AFTER_CALLS)
    assert r.returncode == 0, r.stderr
    cpu, wall = map(float, r.stdout.split())
    assert cpu < 0.1 * wall, (cpu, wall)


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="needs Linux /proc")
def test_many_requested_threads_keep_a_bounded_pool() -> None:
    # threads=200 splits the work into 200 bands (the same result as 1 thread), but the kept
    # workers stop at twice the CPUs (at least 8): the rest of the bands run on the caller.
    rng = np.random.default_rng(7)
    left = rng.integers(0, 256, size=(400, 64), dtype=np.uint8)
    right = np.roll(left, -2, axis=1)
    want = stereodepth.StereoMatcher(num_disparities=16, threads=1).compute(left, right)
    before = len(os.listdir("/proc/self/task"))
    got = stereodepth.StereoMatcher(num_disparities=16, threads=200).compute(left, right)
    after = len(os.listdir("/proc/self/task"))
    np.testing.assert_array_equal(got, want)
    assert after - before <= max(8, 2 * (os.cpu_count() or 1))


_REFUSED_THREADS = """
import resource, sys
import numpy as np
import stereodepth

rng = np.random.default_rng(7)
left = rng.integers(0, 256, size=(24, 64), dtype=np.uint8)
right = np.roll(left, -3, axis=1)
m1 = stereodepth.SemiGlobalMatcher(num_disparities=16, paths=8, threads=1)
m2 = stereodepth.SemiGlobalMatcher(num_disparities=16, paths=8, threads=2)
want = m1.compute(left, right)
with open("/proc/self/status") as f:
    vm = next(int(line.split()[1]) for line in f if line.startswith("VmSize:")) * 1024
# A few MiB more than the process has mapped: too little for a thread's stack (8 MiB).
resource.setrlimit(resource.RLIMIT_AS, (vm + (6 << 20), resource.getrlimit(resource.RLIMIT_AS)[1]))
try:
    got = m2.compute(left, right)
except (RuntimeError, MemoryError) as e:
    print("refused:", e)
    sys.exit(0)
sys.exit(0 if np.array_equal(got, want, equal_nan=True) else 1)
"""


@pytest.mark.skipif(
    not os.path.exists("/proc/self/status"), reason="needs Linux's /proc/self/status"
)
def test_semi_global_does_not_hang_when_threads_are_refused() -> None:
    # The 8-path mode's vertical bands meet at a barrier every row, so each band needs a thread
    # of its own at once: the kept workers ran a band only when one was free, and a call whose
    # worker could not be started (here: no address space for its stack) waited at the barrier
    # forever. It must return the right output or raise, in a fresh process (a forked one
    # reuses the stacks of its parent's threads).
    if stereodepth.build_info()["default_threads"] < 2:
        pytest.skip("the 8-path mode runs one band on one CPU")
    try:
        run = run_python(_REFUSED_THREADS)
    except subprocess.TimeoutExpired:
        pytest.fail("the matcher hung when a worker thread could not be started")
    assert run.returncode == 0, run.stderr


_EXIT_DURING_CALLS = """
import threading, time
import numpy as np
import stereodepth

rng = np.random.default_rng(8)
left = rng.integers(0, 256, size=(48, 96), dtype=np.uint8)
right = np.roll(left, -3, axis=1)
started = threading.Barrier(3)


def loop(make):
    m = make()
    started.wait()
    while True:
        m.compute(left, right)


for make in (
    lambda: stereodepth.StereoMatcher(num_disparities=16, threads=2),
    lambda: stereodepth.SemiGlobalMatcher(num_disparities=16, threads=2),
):
    threading.Thread(target=loop, args=(make,), daemon=True).start()
started.wait()
time.sleep(0.3)
"""


def test_interpreter_exits_cleanly_while_daemon_threads_are_in_kernels() -> None:
    # At exit CPython ends daemon threads that ask for the GIL back; a thread coming back from
    # a kernel then must not take the process down (it aborted in std::terminate, exit -6).
    for _ in range(3):
        run = run_python(_EXIT_DURING_CALLS)
        assert run.returncode == 0, run.stderr
        assert "terminate" not in run.stderr


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
@pytest.mark.skipif(
    stereodepth.build_info()["sanitizers"],
    reason="GCC 12's ASan runtime takes no lock around fork() (it has no fork interceptor), "
    "so a child forked while another thread is inside its malloc can hang there (seen once "
    "in CI); the uninstrumented runs cover this test",
)
def test_fork_while_other_threads_are_in_kernels() -> None:
    # fork() from one Python thread while two others are inside multi-threaded kernel calls
    # (their bands on the kept workers, the pool's lock taken and released all the while): the
    # child has none of those threads and must still match on several threads, 8-path bands
    # that meet at a barrier included. The child makes its own matchers: a matcher locks
    # itself during a call, and a child forked mid-call inherits that lock held.
    import threading
    import warnings

    rng = np.random.default_rng(9)
    left = rng.integers(0, 256, size=(48, 96), dtype=np.uint8)
    right = np.roll(left, -3, axis=1)
    makers = [
        lambda: stereodepth.SemiGlobalMatcher(num_disparities=16, paths=8, threads=2),
        lambda: stereodepth.StereoMatcher(num_disparities=16, threads=3),
    ]
    want = [make().compute(left, right) for make in makers]
    stop = threading.Event()

    def busy(make: Any) -> None:
        m = make()
        while not stop.is_set():
            m.compute(left, right)

    threads = [threading.Thread(target=busy, args=(make,)) for make in makers]
    for t in threads:
        t.start()
    try:
        for _ in range(10):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                pid = os.fork()
            if pid == 0:  # the child: never return into pytest
                code = 1
                try:
                    got = [make().compute(left, right) for make in makers]
                    pairs = zip(got, want, strict=True)
                    code = 0 if all(np.array_equal(a, b, equal_nan=True) for a, b in pairs) else 1
                finally:
                    os._exit(code)
            assert child_exit_code(pid, 30, "a child forked during kernel calls hung") == 0
    finally:
        stop.set()
        for t in threads:
            t.join()
