"""Small defects a new user met in the commands: a valid depth under half a millimetre written
as "no depth" (0) in the millimetre PNGs of ``match`` and ``batch``; ``batch`` exiting 1 after
every output was written when its summary could not be printed. (The third, the advice for a
calibration whose first camera is the right one, is tested in test_match_rectify.py.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("PIL", reason="reading images needs Pillow (the batch extra)")

from PIL import Image

import stereodepth
from stereodepth import cli, disparity_to_depth
from stereodepth.io import read_disparity_pfm, read_image
from stereodepth.sample import sample_pair

#: Where this process imported stereodepth from (the source tree with an in-place build, or
#: site-packages after `pip install .`), for the child processes to import the same.
PYTHON_DIR = Path(stereodepth.__file__).resolve().parents[1]

#: A rig so small that every depth of the sample pair is under half a millimetre (f B =
#: 300 px x 1 um: 0.03 mm at 10 px).
TINY_RIG = ["--focal-px", "300", "--baseline-mm", "0.001"]


def scenes(root: Path, n: int = 2) -> Path:
    """``n`` folders of a left/right sample pair, 96 x 64 px."""
    s = sample_pair(96, 64)
    for i in range(n):
        d = root / f"s{i}"
        d.mkdir(parents=True)
        Image.fromarray(s.left).save(d / "left.png")
        Image.fromarray(s.right).save(d / "right.png")
    return root


# --- 1. millimetre depth: a valid depth is never 0 --------------------------------------------
def test_match_png16_depth_of_a_near_scene_has_no_false_holes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pair = scenes(tmp_path / "in", 1) / "s0"
    out = tmp_path / "out"
    argv = ["match", str(pair / "left.png"), str(pair / "right.png"), *TINY_RIG]
    argv += ["--depth-format", "png16", "--no-preview", "-o", f"{out}/"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    d = read_disparity_pfm(out / "disparity.pfm")
    mm = read_image(out / "depth.png")
    valid = np.isfinite(d)
    assert valid.mean() > 0.5
    # Every depth here is under 0.05 mm: 1 mm (the least valid value) where there is one.
    assert np.array_equal(mm, np.where(valid, 1, 0).astype(np.uint16))
    want = disparity_to_depth(d, focal_px=300.0, baseline_m=1e-6, dtype=np.uint16)
    assert np.array_equal(mm, want)


def test_batch_png16_depth_of_a_near_scene_has_no_false_holes(tmp_path: Path) -> None:
    scenes(tmp_path / "in")
    out = tmp_path / "out"
    argv = ["batch", str(tmp_path / "in"), "-o", str(out), *TINY_RIG, "--num-disparities", "16"]
    assert cli.main([*argv, "--format", "png16", "--threads", "1", "--quiet"]) == 0
    for stem in ("s0", "s1"):
        raw = read_image(out / f"{stem}.disparity.png")
        mm = read_image(out / f"{stem}.depth.png")
        assert (raw > 0).mean() > 0.5
        assert np.array_equal(mm, np.where(raw > 0, 1, 0).astype(np.uint16))


# --- 2. batch: a summary that cannot be printed loses no work ---------------------------------
def run_batch_child(tmp_path: Path, stdout: Any, *extra: str) -> subprocess.CompletedProcess[str]:
    """``stereodepth batch`` of two pairs in a child process, its stdout as given."""
    root = tmp_path / "in"
    if not root.exists():
        scenes(root)
    argv = [sys.executable, "-m", "stereodepth", "batch", str(root), "-o", str(tmp_path / "out")]
    argv += ["--focal-px", "300", "--baseline-mm", "50", "--num-disparities", "16", *extra]
    env = {**os.environ, "PYTHONPATH": str(PYTHON_DIR)}
    kw: dict[str, Any] = {"preexec_fn": lambda: os.close(1)} if stdout == "closed" else {}
    return subprocess.run(
        argv,
        env=env,
        stdout=None if stdout == "closed" else stdout,
        stderr=subprocess.PIPE,
        text=True,
        timeout=300,
        **kw,
    )


def assert_work_saved(tmp_path: Path, status: int = 0) -> None:
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["exit_status"] == status
    for stem in ("s0", "s1"):
        for kind in ("disparity", "depth"):
            assert (tmp_path / "out" / f"{stem}.{kind}.npy").is_file()


def test_batch_whose_reader_went_away_exits_with_the_jobs_status(tmp_path: Path) -> None:
    """``stereodepth batch ... | head -1``, the reader gone before the summary (a pipe with
    its read end closed: every write fails, as once head has exited): the work is saved, so
    the status is the report's (it was 1), quietly (the reader asked for no more)."""
    r, w = os.pipe()
    os.close(r)
    try:
        done = run_batch_child(tmp_path, w)
    finally:
        os.close(w)
    assert (done.returncode, done.stderr) == (0, "")
    assert_work_saved(tmp_path)


@pytest.mark.parametrize(
    ("stdout", "why"),
    [
        pytest.param("closed", "stdout is closed", id="closed"),
        pytest.param("/dev/full", "No space left on device", id="full"),
    ],
)
def test_batch_that_cannot_print_its_summary_says_so_and_keeps_its_status(
    tmp_path: Path, stdout: str, why: str
) -> None:
    """stdout closed (``>&-``: it said nothing and the summary was lost) or full (exit 1 with
    an error, after the work was done): one line naming the report, the report's status."""
    if stdout == "closed":
        done = run_batch_child(tmp_path, "closed")
    else:
        if not Path(stdout).exists():
            pytest.skip("no /dev/full here")
        with open(stdout, "w") as full:
            done = run_batch_child(tmp_path, full)
    report = tmp_path / "out" / "report.json"
    assert done.returncode == 0
    assert done.stderr == (
        f"stereodepth batch: note: cannot print the summary ({why}); the report, {report}, "
        "holds every pair's status\n"
    )
    assert_work_saved(tmp_path)


def test_batch_with_a_failed_pair_and_no_reader_still_exits_1(tmp_path: Path) -> None:
    """The status stays the job's: 1 when a pair failed, the failure on stderr as always."""
    scenes(tmp_path / "in")
    (tmp_path / "in" / "s2").mkdir()
    (tmp_path / "in" / "s2" / "left.png").write_bytes(b"not a png")
    (tmp_path / "in" / "s2" / "right.png").write_bytes(b"not a png")
    r, w = os.pipe()
    os.close(r)
    try:
        done = run_batch_child(tmp_path, w)
    finally:
        os.close(w)
    assert done.returncode == 1
    assert "Traceback" not in done.stderr and "Exception" not in done.stderr
    assert_work_saved(tmp_path, status=1)
