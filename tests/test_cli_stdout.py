"""``calc``, ``eval`` and ``match`` refuse to run with stdout closed (``>&-``): Python then has
no sys.stdout and print() writes nothing, so what they print would be lost without a word."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("PIL", reason="reading images needs Pillow (the batch extra)")

from PIL import Image

import stereodepth
from stereodepth.sample import sample_pair

#: Where this process imported stereodepth from (the source tree with an in-place build, or
#: site-packages after `pip install .`), for the child processes to import the same.
PYTHON_DIR = Path(stereodepth.__file__).resolve().parents[1]
RIG = ["--focal-px", "300", "--baseline-mm", "50", "--threads", "1"]


@pytest.fixture
def pair(tmp_path: Path) -> tuple[Path, Path]:
    s = sample_pair(96, 64)
    Image.fromarray(s.left).save(tmp_path / "l.png")
    Image.fromarray(s.right).save(tmp_path / "r.png")
    return tmp_path / "l.png", tmp_path / "r.png"


@pytest.mark.parametrize(
    "argv",
    [
        pytest.param(["calc", "--baseline-mm", "50", "--focal-px", "300"], id="calc"),
        pytest.param(["calc", "--baseline-mm", "50", "--focal-px", "300", "--json"], id="json"),
        pytest.param(["match", "l.png", "r.png", *RIG, "-o", "out/"], id="match"),
        pytest.param(["eval", "scenes"], id="eval"),
    ],
)
def test_closed_stdout_is_an_error(
    pair: tuple[Path, Path], tmp_path: Path, argv: list[str]
) -> None:
    """``>&-``: Python has no sys.stdout and print() writes nothing; calc exited 0 having
    shown nothing. Now: one line, exit status 1, and no file written."""
    done = subprocess.run(
        [sys.executable, "-m", "stereodepth", *argv],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(PYTHON_DIR)},
        stderr=subprocess.PIPE,
        text=True,
        timeout=300,
        preexec_fn=lambda: os.close(1),
    )
    assert done.returncode == 1
    assert "error: stdout is closed" in done.stderr and done.stderr.count("\n") == 1
    assert not (tmp_path / "out").exists()
