"""Running a job: here on a thread pool (embedded) or on a Dask cluster, with a lock on OUTDIR,
a progress bar and Ctrl-C handling."""

from __future__ import annotations

import contextlib
import datetime as _dt
import logging
import os
import re
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from .. import _validate as check
from .._extras import require
from .compute import process_pair, record_failure
from .job import BatchOptions, Pair, UsageError
from .records import BatchReport, completed_record, jsonable, matcher_options, record_head

#: Pairs in flight in the embedded runner: decoding, writing and fsyncing some overlap the
#: matching of another (which uses every core). See bench/README.md for 1, 2 and 3.
EMBEDDED_IN_FLIGHT = 3
LOCK_NAME = ".stereodepth-batch.lock"


class ClusterLost(Exception):
    """The Dask cluster cannot go on with the job: its scheduler went away mid-job (killed,
    restarted, a connection that dropped), or its workers cannot run stereodepth (it or
    Pillow not installed in their environment, another version, no answer). The job stops,
    and the pairs not done are cancelled, as by Ctrl-C, not failed: no pair is at fault, so
    their earlier outputs are kept."""


#: How long the workers may take to answer the check before the first pair: a worker
#: answers in milliseconds, unless it is stopped or hung.
WORKER_CHECK_TIMEOUT_S = 30.0

# What the check evaluates on each worker, with the builtin eval: a function of this module
# would not exist on a worker with an older stereodepth (nor load on one without it). It
# imports what a pair needs there, stereodepth and Pillow (the [batch] extra's image
# reader), and gives stereodepth's version.
_WORKER_PROBE = "(__import__('stereodepth').__version__, __import__('PIL.Image'))[0]"


def _check_workers(client: Any, stop: threading.Event) -> None:
    """Raises ClusterLost unless every worker of the client's cluster imports this version of
    stereodepth and Pillow, and KeyboardInterrupt when ``stop`` is set meanwhile. A cluster
    with no worker yet is waited for (it may be scaling up) and its first workers checked.

    A worker without stereodepth ended on its first task (the job then waited for ever, or
    failed every pair after three workers died, removing their earlier outputs); one without
    Pillow failed every pair; one with another version wrote outputs that the records credit
    to this one. Workers that join after the check are not checked."""
    from .. import __version__

    try:
        _in_thread(lambda: client.wait_for_workers(1), stop, None)
        versions = _in_thread(
            lambda: client.run(eval, _WORKER_PROBE, {}), stop, WORKER_CHECK_TIMEOUT_S
        )
    except TimeoutError as exc:
        raise ClusterLost(
            f"the Dask workers did not all answer within {WORKER_CHECK_TIMEOUT_S:g} s (a "
            "worker stopped or hung?)"
        ) from exc
    except Exception as exc:  # Dask re-raises a worker's error as a plain Exception
        what = str(exc) if type(exc) is Exception else f"{type(exc).__name__}: {exc}"
        if "ModuleNotFoundError" in what or "ImportError" in what:
            raise ClusterLost(
                f"a Dask worker cannot import what the pairs need ({what}): install "
                f'"stereodepth[batch]=={__version__}" in the workers\' environment'
            ) from exc
        raise ClusterLost(f"the Dask workers could not be checked ({what})") from exc
    other = sorted({str(v) for v in versions.values()} - {__version__})
    if other:
        raise ClusterLost(
            f"the Dask workers run stereodepth {', '.join(other)}, this is {__version__}: "
            f"install stereodepth {__version__} in the workers' environment"
        )


def _in_thread(fn: Callable[[], Any], stop: threading.Event, timeout: float | None) -> Any:
    """``fn()``, called on a thread of its own so that ``stop`` (Ctrl-C) is heard meanwhile
    (KeyboardInterrupt) and a ``timeout`` in seconds kept (TimeoutError; the call is left to
    end on its own)."""
    box: dict[str, Any] = {}

    def call() -> None:
        try:
            box["value"] = fn()
        except BaseException as exc:  # handed to the caller
            box["error"] = exc

    thread = threading.Thread(target=call, name="stereodepth-dask-check", daemon=True)
    thread.start()
    deadline = None if timeout is None else time.monotonic() + timeout
    while thread.is_alive():
        if stop.is_set():
            raise KeyboardInterrupt
        if deadline is not None and time.monotonic() > deadline:
            raise TimeoutError
        thread.join(0.1)
    if "error" in box:
        raise box["error"]
    return box["value"]


@contextlib.contextmanager
def _exclusive(out_dir: Path) -> Iterator[None]:
    """Holds a lock on OUTDIR so that two jobs never write there at once; the lock file
    (:data:`LOCK_NAME`) is removed when the job ends, however it ends (a job killed with
    SIGKILL leaves it, unlocked: the next job takes it).

    The file is removed while it is still locked, so a job that opened it just before must
    find, once it holds the lock, that the file it locked is no longer the one at that path:
    it then starts again with a new file."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    path = out_dir / LOCK_NAME
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise UsageError(f"another stereodepth batch job is writing to {out_dir}") from None
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # removed by the job that held it: lock the new file instead
    try:
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        os.close(fd)


class _Progress:
    """A tqdm bar on stderr (when ``enabled``), or nothing."""

    def __init__(self, total: int, enabled: bool) -> None:
        self._bar: Any = None
        self.failed = 0
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(
                total=total,
                unit="pair",
                file=sys.stderr,
                dynamic_ncols=True,
                desc="stereodepth batch",
            )

    def update(self, record: dict[str, Any]) -> None:
        if record["status"] == "failed":
            self.failed += 1
        if self._bar is not None:
            if self.failed:
                self._bar.set_postfix(failed=self.failed, refresh=False)
            self._bar.update(1)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def _run_embedded(
    todo: list[tuple[int, Pair]],
    options: BatchOptions,
    done: Callable[[int, dict[str, Any]], None],
    threads: int | None,
) -> None:
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    pool = ThreadPoolExecutor(max_workers=EMBEDDED_IN_FLIGHT, thread_name_prefix="stereodepth")
    futures: dict[Any, int] = {}
    handled: set[Any] = set()
    try:
        # Submitted inside the try, with Ctrl-C and SIGTERM held until every future is in
        # `futures`: one that landed inside pool.submit (after a worker had started its pair,
        # before the future was recorded) left that pair running unwatched, reported as
        # cancelled while it wrote its files. A signal held meanwhile is raised again here.
        from ..cli import signals_held

        with signals_held() as caught:
            for i, p in todo:
                futures[pool.submit(process_pair, p, options, threads)] = i
        for sig in dict.fromkeys(caught):
            signal.raise_signal(sig)
        pending = set(futures)
        while pending:
            finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
            for f in finished:
                done(futures[f], f.result())
                handled.add(f)
    except KeyboardInterrupt:
        # Let the pairs in flight finish (their files are then complete); drop the rest.
        pool.shutdown(wait=True, cancel_futures=True)
        for f, i in futures.items():
            if f not in handled and f.done() and not f.cancelled():
                done(i, f.result())
        raise
    pool.shutdown(wait=True)


def _run_dask(
    todo: list[tuple[int, Pair]],
    options: BatchOptions,
    done: Callable[[int, dict[str, Any]], None],
    threads: int | None,
    client: Any,
    stop: threading.Event,
) -> None:
    """Runs the pairs on the client's cluster until all are done or ``stop`` is set (Ctrl-C,
    see :func:`_sigint_as_flag`): then the tasks not started are cancelled, the results that
    already arrived are kept, and KeyboardInterrupt is raised here, outside Dask's calls."""
    import queue

    if stop.is_set():  # Ctrl-C while the cluster started: no pair is sent
        raise KeyboardInterrupt
    _check_workers(client, stop)
    run_id = uuid.uuid4().hex[:8]
    futures = {}
    for i, p in todo:
        f = client.submit(
            process_pair, p, options, threads, key=f"stereodepth-{run_id}-{i}", pure=False
        )
        futures[f] = i
    pairs = dict(todo)
    arrived: queue.SimpleQueue[Any] = queue.SimpleQueue()
    for f in futures:
        f.add_done_callback(arrived.put)  # called from Dask's thread when the task ends
    pending = set(futures)
    while pending:
        if stop.is_set():
            client.cancel([f for f in pending if not f.done()])
            for f in pending:
                if f.done() and f.status == "finished":
                    done(futures[f], f.result())
            raise KeyboardInterrupt
        try:
            f = arrived.get(timeout=0.2)
        except queue.Empty:
            continue
        pending.discard(f)  # Dask calls a future's callback once
        i = futures[f]
        if f.status == "cancelled":
            # Not by this job (it cancels only when stopped, above): the scheduler is gone,
            # and with it every pair not done. Those were each recorded as failed and their
            # earlier outputs removed, although no pair was at fault and a worker may still
            # be writing one.
            try:
                f.result()
            except Exception as exc:
                why = getattr(exc, "reason", None) or type(exc).__name__
            else:  # pragma: no cover - a cancelled future has no result
                why = "cancelled"
            raise ClusterLost(f"the Dask scheduler was lost mid-job ({why})")
        try:
            record = f.result()
        except Exception as exc:  # the task itself never raises: a worker kept dying
            head = record_head(pairs[i], "failed", f"{type(exc).__name__}: {exc}", options)
            record = jsonable(record_failure(pairs[i], options, head))
        done(i, record)


#: A dask.distributed scheduler's address: [PROTOCOL://]HOST:PORT, HOST a name, an IPv4
#: address or a bracketed IPv6 address.
_SCHEDULER_ADDRESS = re.compile(
    r"(?:(?P<protocol>[a-z][a-z0-9+.-]*)://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[^\s:/\[\]]+)"
    r":(?P<port>[0-9]{1,5})/?"
)
_SCHEDULER_PROTOCOLS = ("tcp", "tls", "ws", "wss", "ucx")


def check_scheduler_address(scheduler: str) -> None:
    """Raises UsageError, naming ``--scheduler`` and the value, unless ``scheduler`` is a
    dask.distributed address ``[tcp|tls|ws|wss|ucx://]HOST:PORT`` with a port in 1..65535.
    Whether a scheduler answers there is known only when connecting."""
    hint = "expected a Dask scheduler address tcp://HOST:PORT"
    m = _SCHEDULER_ADDRESS.fullmatch(scheduler)
    if m is None:
        raise UsageError(f"--scheduler {scheduler!r}: {hint}")
    protocol = m.group("protocol")
    if protocol is not None and protocol not in _SCHEDULER_PROTOCOLS:
        raise UsageError(
            f"--scheduler {scheduler!r}: unknown protocol {protocol!r} "
            f"({', '.join(_SCHEDULER_PROTOCOLS)}); {hint}"
        )
    if not 1 <= int(m.group("port")) <= 65535:
        raise UsageError(f"--scheduler {scheduler!r}: the port must be in 1..65535; {hint}")


def check_runner(
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    threads: int | None = None,
    progress: bool = False,
) -> None:
    """Raises UsageError for runner options that no pair can run with, and ImportError (one
    line, with the install hint) when what they need is not installed: dask.distributed for
    ``scheduler`` or ``workers``, tqdm for ``progress``."""
    if scheduler is not None and workers is not None:
        raise UsageError("give --scheduler or --workers, not both")
    if scheduler is not None:
        check_scheduler_address(scheduler)
    if workers is not None and workers < 1:
        raise UsageError(f"--workers must be an integer >= 1, got {workers}")
    if workers is not None and workers > (cores := check.available_cores()):
        # Each worker is a process with its own matcher and buffers: more than the cores only
        # compete for them, and thousands took minutes (and gigabytes) to start, deaf to
        # Ctrl-C while the cluster started.
        raise UsageError(
            f"--workers must be at most {cores} (the cores this process may use), got {workers}"
        )
    from ..cli import threads_out_of_range

    if why := threads_out_of_range(threads):
        raise UsageError(why)
    if scheduler is not None or workers is not None:
        require("distributed", "running on Dask (--scheduler, --workers)")
    if progress:
        require("tqdm", "the progress bar (or give --quiet)")


def run_batch(
    pairs: Sequence[Pair],
    options: BatchOptions,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    threads: int | None = None,
    progress: bool = False,
    on_result: Callable[[dict[str, Any]], None] | None = None,
    notes: Sequence[str] = (),
) -> BatchReport:
    """Runs a job: every pair not already done, on this machine (default), on a local Dask
    cluster of ``workers`` processes, or on the Dask cluster at ``scheduler``.

    Pairs need their calibration (:func:`resolve_calibration`). ``threads`` is the matcher's
    thread count per pair; by default every core, the cores / ``workers`` on a local cluster,
    and on a ``scheduler`` cluster a worker's cores / its number of threads.
    ``on_result`` is called in this thread with each record as it arrives. Ctrl-C
    (KeyboardInterrupt) stops the job: the pairs in flight finish, the rest are ``cancelled``,
    and the report says ``interrupted``. A Dask scheduler lost mid-job, or Dask workers
    without this version of stereodepth or Pillow (or that do not answer within
    ``WORKER_CHECK_TIMEOUT_S``; checked before the first pair), stop it the same way, its pairs
    not done ``cancelled`` (their earlier outputs kept), and the report's ``error`` says so
    (exit status 1). Writes ``<stem>.*`` files into ``options.out_dir``;
    the caller writes the report."""
    check_runner(scheduler=scheduler, workers=workers, threads=threads, progress=progress)
    if scheduler is not None:
        # The cluster's workers run in folders of their own: paths relative to this one
        # found no images there (every pair failed) or wrote the outputs elsewhere.
        pairs, options = _absolute(pairs, options)
    out_dir = options.out_dir
    # OUTDIR and its missing parents, deepest first: -o new/run/out made all three.
    created = [d for d in (out_dir, *out_dir.parents) if not d.exists()]
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # what the command's checks cannot foresee (/proc, /sys, full disk)
        raise UsageError(f"OUTDIR {out_dir} cannot be created: {exc.strerror or exc}") from None
    try:
        return _run_locked(pairs, options, scheduler, workers, threads, progress, on_result, notes)
    except UsageError:
        # e.g. the scheduler did not answer: leave no empty OUTDIR behind, nor the folders
        # made for it (rmdir removes only an empty folder)
        for folder in created:
            try:
                folder.rmdir()
            except OSError:
                break
        raise


def _absolute(pairs: Sequence[Pair], options: BatchOptions) -> tuple[list[Pair], BatchOptions]:
    """The pairs' images and calibration files and OUTDIR as absolute paths (links kept)."""
    import dataclasses

    def absolute(p: Path | None) -> Path | None:
        return None if p is None else Path(os.path.abspath(p))

    done = [
        dataclasses.replace(
            p,
            left=Path(os.path.abspath(p.left)),
            right=Path(os.path.abspath(p.right)),
            calib_file=absolute(p.calib_file),
        )
        for p in pairs
    ]
    return done, dataclasses.replace(options, out_dir=Path(os.path.abspath(options.out_dir)))


def _run_locked(
    pairs: Sequence[Pair],
    options: BatchOptions,
    scheduler: str | None,
    workers: int | None,
    threads: int | None,
    progress: bool,
    on_result: Callable[[dict[str, Any]], None] | None,
    notes: Sequence[str],
) -> BatchReport:
    """:func:`run_batch` once OUTDIR exists."""
    from ..io import remove_temp_files

    out_dir = options.out_dir
    started = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    records: list[dict[str, Any] | None] = [None] * len(pairs)
    removed = 0
    interrupted = False
    error = None
    runner = "embedded"
    before: dict[int, tuple[int, int, int] | None] = {}  # the records of the pairs to do
    with _exclusive(out_dir):
        bar = _Progress(len(pairs), progress)

        def done(i: int, record: dict[str, Any]) -> None:
            records[i] = record
            bar.update(record)
            if on_result is not None:
                on_result(record)

        try:
            removed += len(remove_temp_files(out_dir))
            if not options.force:
                _refuse_replacing_other_images(pairs, options)
                _refuse_replacing_files_of_no_record(pairs, options)
            todo: list[tuple[int, Pair]] = []
            for i, p in enumerate(pairs):
                earlier = None if options.force else completed_record(p, options)
                if earlier is None:
                    todo.append((i, p))
                    before[i] = _record_stamp(p, options)
                    continue
                keep = ("time_s", "density", "width", "height", "outputs")
                head = record_head(p, "skipped", options=options)
                done(i, {**head, **{k: earlier.get(k) for k in keep}})
            if scheduler is None and workers is None:
                if todo:
                    _run_embedded(todo, options, done, threads)
            else:
                with (
                    _sigint_as_flag() as stop,
                    _dask_client(scheduler, workers, threads) as (client, runner, task_threads),
                ):
                    if todo:
                        _run_dask(todo, options, done, task_threads, client, stop)
        except KeyboardInterrupt:
            interrupted = True
        except ClusterLost as exc:  # the pairs not done are cancelled, as below
            error = str(exc)
        finally:
            bar.close()
            removed += len(remove_temp_files(out_dir))
    final = []
    for i, p in enumerate(pairs):
        rec = records[i]
        if rec is None:
            # Interrupted (or the scheduler lost): a pair whose result did not reach us may
            # have finished anyway, its record then rewritten by this job. A record as it was
            # before (--force, which redoes complete pairs), or of a pair this job never
            # started, is the run before's: this job did not redo that pair.
            redone = i in before and _record_stamp(p, options) != before[i]
            earlier = completed_record(p, options) if redone else None
            rec = record_head(p, "cancelled", options=options)
            if earlier is not None:
                rec.update(
                    {
                        k: earlier.get(k)
                        for k in ("status", "time_s", "density", "width", "height", "outputs")
                    }
                )
        final.append(rec)
    return BatchReport(
        pairs=final,
        runner=runner,
        elapsed_s=time.perf_counter() - t0,
        interrupted=interrupted,
        error=error,
        started=started,
        removed_temp_files=removed,
        notes=list(notes),
        method=options.method,
        matcher_options=matcher_options(options),
        rectification=None if options.rectification is None else options.rectification.as_dict(),
        force=options.force,
    )


def _refuse_replacing_other_images(pairs: Sequence[Pair], options: BatchOptions) -> None:
    """UsageError, before any pair runs, when OUTDIR holds a pair's complete outputs made from
    other images: a second job into the same OUTDIR whose stems repeat the first's (KITTI
    2012's and 2015's training/image_2/000000_10.png are both pair 000000_10) replaced the
    first job's results without a word. ``--force`` replaces them.

    Records name their images by real path (:func:`~.records.file_stamp`); one naming them by
    a relative path (written before that) cannot be compared and is taken as the same pair."""
    from .job import read_record

    for p in pairs:
        record = read_record(options.record_path(p.stem))
        if record is None or record.get("status") != "ok":
            continue  # a failed pair's record: its outputs were removed, nothing to lose
        try:
            before = [record["inputs"][side]["path"] for side in ("left", "right")]
        except (KeyError, TypeError):
            continue
        if not all(isinstance(b, str) and os.path.isabs(b) for b in before):
            continue
        if not all(_same_file(b, now) for b, now in zip(before, (p.left, p.right), strict=True)):
            raise UsageError(
                f"OUTDIR {options.out_dir} holds the outputs of pair {p.stem!r} made from other "
                f"images ({before[0]}, {before[1]}; this job's are {p.left}, {p.right}): "
                "choose another OUTDIR (-o), or give --force to replace them"
            )


def _refuse_replacing_files_of_no_record(pairs: Sequence[Pair], options: BatchOptions) -> None:
    """UsageError, before any pair runs, when a file is at one of a pair's output paths and
    the pair's record does not list it (or there is none): no batch job wrote it, so it is
    the user's (``l.disparity.npy`` of their own, beside the pair ``l``), and it was replaced
    without a word. ``--force`` replaces it. A job killed mid-pair leaves only files that its
    record, written before the first of them, lists."""
    from .job import read_record
    from .records import earlier_outputs

    for p in pairs:
        record = options.record_path(p.stem)
        if record.exists() and read_record(record) is None:
            continue  # a record of ours that cannot be read (edited by hand): the pair is redone
        listed = earlier_outputs(p, options)
        for path in options.output_paths(p.stem).values():
            if path not in listed and os.path.lexists(path):
                raise UsageError(
                    f"OUTDIR {options.out_dir} holds {path.name}, which pair {p.stem!r} would "
                    "write and no batch job's record lists (a file of yours?): move it, "
                    "choose another OUTDIR (-o), or give --force to replace it"
                )


def _same_file(recorded: str, path: Path) -> bool:
    """Whether a record's absolute path names the file at ``path`` (a link to it too)."""
    try:
        return os.path.samefile(recorded, path)
    except OSError:  # either is gone
        return recorded == os.path.realpath(path)


def _record_stamp(pair: Pair, options: BatchOptions) -> tuple[int, int, int] | None:
    """(inode, size, mtime_ns) of a pair's record, None when it is missing: a record
    rewritten (atomically: a new file) has another stamp."""
    try:
        st = options.record_path(pair.stem).stat()
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


@contextlib.contextmanager
def _sigint_handled_by(handler: Any) -> Iterator[None]:
    """SIGINT goes to ``handler`` (a function or ``signal.SIG_IGN``) for the block's duration,
    then the previous handler comes back. A no-op outside the main thread, where signal
    handlers cannot be set."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _ctrl_c_witness() -> Iterator[Callable[[], bool]]:
    """A small process of this process group that a Ctrl-C ends, for a block during which
    this process ignores SIGINT (while a local cluster starts: a Ctrl-C then was lost, and the
    job ran every pair and ended with status 0). Yields a function that says, after the
    block, whether the witness ended on its own, that is whether SIGINT reached the group.
    In the main thread of a POSIX process only (elsewhere SIGINT is not ignored: the function
    says False)."""
    import subprocess

    if (
        os.name != "posix"
        or threading.current_thread() is not threading.main_thread()
        or not sys.executable  # an embedded interpreter: no witness
    ):
        yield lambda: False
        return
    witness = subprocess.Popen(
        [sys.executable, "-S", "-E", "-c", "import time\nwhile True: time.sleep(60)"],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,  # a Ctrl-C during its start is a KeyboardInterrupt there
    )
    ended: list[bool] = []
    try:
        yield lambda: bool(ended and ended[0])
    finally:
        ended.append(witness.poll() is not None)
        if not ended[0]:
            witness.kill()
        witness.wait()


@contextlib.contextmanager
def _sigint_as_flag() -> Iterator[threading.Event]:
    """For the block's duration, Ctrl-C (SIGINT) sets the returned event instead of raising
    KeyboardInterrupt wherever the main thread happens to be.

    dask.distributed's blocking calls are not safe to interrupt: a KeyboardInterrupt that lands
    inside one can leave its event loop thread printing a traceback. The Dask runner checks the
    event between calls and stops the job itself, and the cluster then shuts down in order; a
    second Ctrl-C raises KeyboardInterrupt as usual. Only Python's default handler is replaced:
    an application's own handler, an ignored SIGINT and threads other than the main one are
    left alone (the event is then never set)."""
    stop = threading.Event()

    def handler(signum: int, frame: Any) -> None:
        if stop.is_set():  # a second Ctrl-C: the user will not wait for the orderly stop
            raise KeyboardInterrupt
        stop.set()

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield stop
        return
    with _sigint_handled_by(handler):
        yield stop


#: Seconds to wait for the scheduler at --scheduler: to connect, and then to answer.
SCHEDULER_TIMEOUT_S = 10


def _handshake(scheduler: str, timeout: float) -> None:
    """Raises UsageError, naming ``--scheduler``, unless a dask.distributed peer at
    ``scheduler`` completes the protocol's handshake within ``timeout`` seconds.

    dask.distributed's Client bounds only the TCP connect: a server that accepts the
    connection and never answers (an HTTP server on that port) kept it waiting for ever, and
    one that sends other bytes (an SSH banner) had them read as a frame length, a MemoryError
    for exabytes. The handshake runs on an event loop of its own in a thread of its own, so
    that a caller inside a running event loop (a notebook) is not disturbed."""
    import asyncio
    import concurrent.futures

    from distributed.comm.core import connect

    async def greet() -> None:
        # connect's own timeout ends its retries of a refused or silent connect (OSError);
        # the outer one, a little later, the wait for the peer's half of the handshake.
        comm = await asyncio.wait_for(connect(scheduler, timeout=timeout), timeout + 2)  # type: ignore[no-untyped-call]
        await comm.close()

    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        try:
            pool.submit(asyncio.run, greet()).result()
        except (asyncio.TimeoutError, TimeoutError) as exc:
            raise UsageError(
                f"--scheduler {scheduler!r}: no Dask scheduler answered within {timeout + 2:g} "
                "s (something that is not one may be listening there)"
            ) from exc
        except OSError as exc:
            raise UsageError(
                f"--scheduler {scheduler!r}: cannot reach the Dask scheduler: {exc}"
            ) from exc
        except MemoryError as exc:
            raise UsageError(
                f"--scheduler {scheduler!r}: what answered there is not a Dask scheduler "
                "(it sent bytes that read as an impossible message size)"
            ) from exc
        except Exception as exc:  # what the peer sent was not the protocol
            raise UsageError(
                f"--scheduler {scheduler!r}: what answered there is not a Dask scheduler "
                f"({type(exc).__name__}: {exc})"
            ) from exc


@contextlib.contextmanager
def _dask_client(
    scheduler: str | None, workers: int | None, threads: int | None
) -> Iterator[tuple[Any, str, int | None]]:
    from ..cli import signals_held

    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise UsageError(
            'running on Dask needs dask.distributed: pip install "stereodepth[batch]"'
        ) from exc
    if scheduler is not None:
        # The address check takes a trailing "/" (HOST:PORT/, as a URL's may end); Dask's
        # parser does not: it read the port as "8786/", "not a Dask scheduler".
        scheduler = scheduler.removesuffix("/")
        _handshake(scheduler, SCHEDULER_TIMEOUT_S)
        try:
            client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s")  # type: ignore[no-untyped-call]
        except (OSError, ValueError) as exc:
            raise UsageError(
                f"--scheduler {scheduler!r}: cannot reach the Dask scheduler: {exc}"
            ) from exc
        except Exception as exc:  # a Dask peer that is not a scheduler (a worker's address)
            raise UsageError(
                f"--scheduler {scheduler!r}: what answered there speaks Dask's protocol but is "
                f"not a scheduler (a worker's address?): {type(exc).__name__}: {exc}"
            ) from exc
        with client:
            yield client, f"dask {scheduler}", threads
        return
    assert workers is not None
    task_threads = threads if threads is not None else max(1, check.available_cores() // workers)
    # The scheduler's HTTP server binds a free loopback port: with dashboard_address=None it
    # would still try port 8787 and warn (or fail) when that is taken.
    # Ctrl-C in a terminal reaches every process of the group: the worker processes start with
    # SIGINT ignored (their children inherit it), so that this process alone stops the job
    # and shuts the cluster down, rather than each worker dying with a traceback. This
    # process ignores it too meanwhile; the witness hears a Ctrl-C of those seconds for it.
    # SIGTERM (stereodepth's main handles it as Ctrl-C) is held the same way meanwhile.
    with (
        _ctrl_c_witness() as witness,
        signals_held((signal.SIGTERM,)) as sigterm,
        _sigint_handled_by(signal.SIG_IGN),
    ):
        cluster = LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            silence_logs=logging.ERROR,
        )
    if witness():  # the handler in place now (_sigint_as_flag's: the job stops) gets it
        signal.raise_signal(signal.SIGINT)
    if sigterm:  # likewise, through the SIGTERM handler in place now
        signal.raise_signal(signal.SIGTERM)
    with cluster, Client(cluster) as client:  # type: ignore[no-untyped-call]
        yield client, f"local dask cluster of {workers} worker processes", task_threads
