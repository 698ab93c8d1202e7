"""SIGTERM (what ``timeout``, ``kill`` and process managers send) stops a command as Ctrl-C
does, through the same clean-up, with one line "terminated" and exit status 143; Ctrl-C keeps
130. Real subprocesses, real signals: each command runs under a small driver that slows one
step down and says on stderr when it is there, so that the signal lands mid-run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("PIL", reason="reading images needs Pillow (the batch extra)")

from PIL import Image

import stereodepth
from stereodepth.sample import sample_pair

#: Where this process imported stereodepth from (the source tree with an in-place build, or
#: site-packages after `pip install .`), for the child processes to import the same.
PYTHON_DIR = Path(stereodepth.__file__).resolve().parents[1]

#: Runs ``main(argv)`` with ``module.attribute`` wrapped: the wrapper prints READY on stderr,
#: then sleeps ``pause`` seconds before calling the original (the signal lands in the sleep).
#: One write(2) of the whole line: batch's worker threads call the wrapper at once, and
#: print()'s two writes (the text, then the newline) interleaved into "READYREADY", never
#: read as READY, so the test waited for a line that never came (seen once in CI).
DRIVER = """
import importlib, os, sys, time
module, attribute, pause = sys.argv[1], sys.argv[2], float(sys.argv[3])
target = importlib.import_module(module)
original = getattr(target, attribute)
def slow(*args, **kwargs):
    os.write(2, b"READY\\n")
    time.sleep(pause)
    return original(*args, **kwargs)
setattr(target, attribute, slow)
from stereodepth.cli import main
sys.exit(main(sys.argv[4:]))
"""


def start(
    cwd: Path, module: str, attribute: str, pause: float, *argv: str
) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(PYTHON_DIR)}
    return subprocess.Popen(
        [sys.executable, "-c", DRIVER, module, attribute, str(pause), *argv],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def signal_when_ready(proc: subprocess.Popen[str], sig: int) -> tuple[int, str, str]:
    """Sends ``sig`` once the driver said READY; the exit status, stdout and the rest of
    stderr."""
    assert proc.stderr is not None
    deadline = time.monotonic() + 120
    while True:
        line = proc.stderr.readline()
        if not line or time.monotonic() > deadline:
            # Say why, and close the pipes (left open, they were reported as ResourceWarnings
            # of whatever test ran next).
            if line:
                proc.kill()
            _, err = proc.communicate(timeout=120)
            raise AssertionError(f"the command ended before READY ({proc.returncode}): {err}")
        if line.strip() == "READY":
            break
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    return proc.returncode, out, err


@pytest.fixture
def pair(tmp_path: Path) -> tuple[str, str]:
    s = sample_pair(96, 64)
    Image.fromarray(s.left).save(tmp_path / "l.png")
    Image.fromarray(s.right).save(tmp_path / "r.png")
    return "l.png", "r.png"


RIG = ["--focal-px", "100", "--baseline-mm", "100", "--threads", "1"]

SIGNALS = [
    pytest.param(signal.SIGTERM, 143, "terminated", id="SIGTERM"),
    pytest.param(signal.SIGINT, 130, "interrupted", id="SIGINT"),
]


@pytest.mark.parametrize(("sig", "status", "word"), SIGNALS)
def test_match_stopped_mid_write_keeps_the_earlier_set(
    tmp_path: Path, pair: tuple[str, str], sig: int, status: int, word: str
) -> None:
    """Signalled while writing its outputs (the disparity and depth written, the cloud not
    yet), match leaves the earlier run's set as it was, no new file and no temporary file,
    prints one line and exits 143 for SIGTERM (it was killed outright: a new disparity
    beside the old cloud), 130 for Ctrl-C."""
    pytest.importorskip("matplotlib", reason="the previews need the plot extra")
    out = tmp_path / "out"
    first = subprocess.run(
        [sys.executable, "-m", "stereodepth", "match", *pair, *RIG, "--ply", "-o", "out/"],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(PYTHON_DIR)},
        capture_output=True,
        text=True,
    )
    assert first.returncode == 0, first.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert set(before) == {
        "disparity.pfm",
        "depth.npy",
        "disparity-preview.png",
        "depth-preview.png",
        "points.ply",
        ".stereodepth-match.json",  # the run's record of its files
    }
    argv = ["match", *pair, *RIG, "--num-disparities", "16", "--ply", "--no-preview"]
    proc = start(tmp_path, "stereodepth.pointcloud", "write_ply", 60, *argv, "-o", "out/")
    code, stdout, err = signal_when_ready(proc, sig)
    assert code == status
    assert err == f"stereodepth match: {word}\n"
    assert stdout == ""
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


@pytest.mark.parametrize(("sig", "status", "word"), SIGNALS)
def test_match_signalled_once_the_set_is_in_place_ends_as_done(
    tmp_path: Path, pair: tuple[str, str], sig: int, status: int, word: str
) -> None:
    """A signal that lands after the new set was renamed into place (here while the run's
    record of its files is written) no longer ends the run with 143 or 130, which say that
    the earlier set was left as it was: the run is done, exit 0, its summary printed, the
    new set and its record in place. (A SIGTERM to `match` 0.3 s in exited 143 with the
    new set in the folder.)"""
    out = tmp_path / "out"
    argv = ["match", *pair, *RIG, "--num-disparities", "16", "--no-preview", "--json"]
    proc = start(tmp_path, "stereodepth.match_command", "_write_manifest", 1, *argv, "-o", "out/")
    code, stdout, err = signal_when_ready(proc, sig)
    assert code == 0, err
    assert word not in err and "Traceback" not in err
    summary = json.loads(stdout)
    assert set(summary["outputs"]) == {"disparity", "depth"}
    assert sorted(p.name for p in out.iterdir()) == [
        ".stereodepth-match.json",
        "depth.npy",
        "disparity.pfm",
    ]
    record = json.loads((out / ".stereodepth-match.json").read_text())
    assert set(record["files"]) == {"depth.npy", "disparity.pfm"}


def test_match_exit_status_after_its_outputs_are_committed(
    tmp_path: Path,
    pair: tuple[str, str],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A Ctrl-C or SIGTERM raised just after the held commit (between two steps of the
    run's end, where no handler holds it) ends the run as done: exit 0, not 130 or 143."""
    from stereodepth import cli, match_command

    def committed_then_signalled() -> None:
        cli.outputs_committed()
        raise cli.Terminated

    monkeypatch.setattr(match_command, "outputs_committed", committed_then_signalled)
    monkeypatch.chdir(tmp_path)
    code = cli.main(["match", *pair, *RIG, "--num-disparities", "16", "--no-preview"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "terminated" not in err
    assert (tmp_path / "disparity.pfm").is_file() and (tmp_path / "depth.npy").is_file()


@pytest.mark.parametrize(("sig", "status", "word"), SIGNALS)
def test_batch_stopped_like_ctrl_c(
    tmp_path: Path, pair: tuple[str, str], sig: int, status: int, word: str
) -> None:
    """Signalled with a pair in flight, batch lets it finish, cancels the rest, writes its
    report (exit_status 143 for SIGTERM), removes its lock and exits with one line on
    stderr; the same command then resumes. SIGTERM used to kill it outright: the lock
    left, no report."""
    inp = tmp_path / "in"
    inp.mkdir()
    s = sample_pair(96, 64)
    for stem in ("a", "b", "c", "d", "e"):
        Image.fromarray(s.left).save(inp / f"{stem}_left.png")
        Image.fromarray(s.right).save(inp / f"{stem}_right.png")
    argv = ["batch", "in", "-o", "out", "--quiet", *RIG, "--num-disparities", "16"]
    proc = start(tmp_path, "stereodepth.batch.runners", "process_pair", 2, *argv)
    code, _, err = signal_when_ready(proc, sig)
    assert code == status, err
    assert err.endswith(f"stereodepth batch: {word}\n") and "Traceback" not in err
    assert err.count(word) == 1
    out = tmp_path / "out"
    assert not (out / ".stereodepth-batch.lock").exists()
    report = json.loads((out / "report.json").read_text())
    assert report["interrupted"] is True and report["exit_status"] == status
    statuses = sorted(p["status"] for p in report["pairs"])
    assert "cancelled" in statuses and "ok" in statuses
    assert not [
        p.name
        for p in out.iterdir()
        if ".stereodepth-" in p.name and p.name[0] == "." and p.name != ".stereodepth-match.json"
    ]

    again = subprocess.run(
        [sys.executable, "-m", "stereodepth", *argv],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(PYTHON_DIR)},
        capture_output=True,
        text=True,
    )
    assert again.returncode == 0, again.stderr
    report = json.loads((out / "report.json").read_text())
    assert {p["status"] for p in report["pairs"]} <= {"ok", "skipped"}
    assert "skipped" in {p["status"] for p in report["pairs"]}


def test_calc_sigterm_outside_a_command_is_not_caught() -> None:
    """The handler is in place for the command's duration only: main leaves SIGTERM's
    handler as it found it."""
    from stereodepth.cli import main

    before = signal.getsignal(signal.SIGTERM)
    assert main(["calc", "--baseline-mm", "50", "--focal-px", "300", "--json"]) == 0
    assert signal.getsignal(signal.SIGTERM) is before


#: Runs ``main(argv)`` with matplotlib's import made slow, and a Ctrl-C or SIGTERM during it
#: turned into ImportError, as pybind11 turns any exception in a compiled module's set-up
#: (matplotlib's ft2font, _path ...): the first import says READY, then sleeps 5 s.
IMPORT_DRIVER = """
import importlib, os, sys, time
original = importlib.import_module
slowed = []
def slow(name, *args, **kwargs):
    if name.startswith("matplotlib") and not slowed:
        slowed.append(name)
        os.write(2, b"READY\\n")
        try:
            time.sleep(5)
        except BaseException as exc:
            raise ImportError(f"initialization failed: {type(exc).__name__}") from exc
    return original(name, *args, **kwargs)
importlib.import_module = slow
from stereodepth.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize(("sig", "status", "word"), SIGNALS)
def test_match_signalled_while_matplotlib_loads_stops_cleanly(
    tmp_path: Path, pair: tuple[str, str], sig: int, status: int, word: str
) -> None:
    """A Ctrl-C while the previews' matplotlib loaded was read as its absence ("colour maps
    need matplotlib", exit 1, the extra installed), and could abort the interpreter at exit:
    the import now runs with the signals held, which act once it is done."""
    pytest.importorskip("matplotlib", reason="the previews need the plot extra")
    argv = ["match", *pair, *RIG, "-o", "out/"]
    proc = subprocess.Popen(
        [sys.executable, "-c", IMPORT_DRIVER, *argv],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(PYTHON_DIR)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    code, stdout, err = signal_when_ready(proc, sig)
    assert (code, err) == (status, f"stereodepth match: {word}\n")
    assert stdout == ""
    assert not (tmp_path / "out").exists()


def test_ctrl_c_while_the_subcommands_load_is_one_line() -> None:
    # A Ctrl-C in the first moments (the subcommands' modules loading in build_parser) was a
    # KeyboardInterrupt traceback and a death by the signal.
    proc = start(Path.cwd(), "stereodepth.cli", "build_parser", 60, "calc", "--help")
    code, stdout, err = signal_when_ready(proc, signal.SIGINT)
    assert (code, err, stdout) == (130, "stereodepth: interrupted\n", "")
