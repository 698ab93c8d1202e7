"""The README runs as written: every ```python block, and every `stereodepth calc` command.

Each block runs on its own (a fresh namespace, as a reader pastes it) in a temporary folder
that holds the files the README names: ``im0.png``/``im1.png`` (a shared scene, else a
synthetic random-dot pair), a Middlebury ``calib.txt`` and ``left.npy``/``right.npy`` stacks.
Whatever blocks the README has are run, so a new section is tested as soon as it is written.
A block is skipped, with the reason, only when it imports an optional package that is not
installed or opens a data file that none of these provide.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
_FENCE = re.compile(r"^```(\w*)[ \t]*\n(.*?)^```[ \t]*$", re.S | re.M)
#: The scene copied in as im0.png / im1.png when the shared data are present.
SCENE = "mb2003-teddy"


def data_dir() -> Path:
    """The shared scenes, found as tests/conftest.py finds them."""
    env = os.environ.get("STEREODEPTH_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared/data/stereo"


def _blocks(language: str) -> list[tuple[int, str]]:
    text = README.read_text(encoding="utf-8")
    return [
        (text.count("\n", 0, m.start()) + 1, m.group(2))
        for m in _FENCE.finditer(text)
        if m.group(1) == language
    ]


PYTHON_BLOCKS = _blocks("python")


def test_readme_has_python_blocks() -> None:
    assert len(PYTHON_BLOCKS) >= 4


def _random_dot_pair(shape: tuple[int, int], shift: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    right = rng.integers(0, 256, shape, dtype=np.uint8)
    left = np.roll(right, shift, axis=1)  # the left image sees everything `shift` px right
    return left, right


@pytest.fixture
def readme_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working folder with the files the README's examples open."""
    scene = data_dir() / SCENE
    if (scene / "left.png").is_file() and (scene / "right.png").is_file():
        shutil.copyfile(scene / "left.png", tmp_path / "im0.png")
        shutil.copyfile(scene / "right.png", tmp_path / "im1.png")
    elif importlib.util.find_spec("PIL") is not None:
        from PIL import Image

        left, right = _random_dot_pair((120, 200), 12)
        Image.fromarray(left).save(tmp_path / "im0.png")
        Image.fromarray(right).save(tmp_path / "im1.png")
    (tmp_path / "calib.txt").write_text(
        "cam0=[1038.018 0 322.037; 0 1038.018 243.393; 0 0 1]\n"
        "cam1=[1038.018 0 375.308; 0 1038.018 243.393; 0 0 1]\n"
        "doffs=53.271\nbaseline=176.252\nwidth=718\nheight=496\nndisp=73\n",
        encoding="ascii",
    )
    stacks = [_random_dot_pair((48, 160), 5 + k) for k in range(3)]
    np.save(tmp_path / "left.npy", np.stack([left for left, _ in stacks]))
    np.save(tmp_path / "right.npy", np.stack([right for _, right in stacks]))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _run_block(line: int, code: str, folder: Path) -> dict[str, Any]:
    namespace: dict[str, Any] = {"__name__": "__readme__"}
    try:
        exec(compile(code, f"{README}:{line}", "exec"), namespace)
    except ImportError as exc:  # ModuleNotFoundError, or our "pip install ..." hint
        name = exc.name or ""
        if name.split(".")[0] == "stereodepth":
            raise  # our own package: a broken example, never a skip
        what = name or str(exc)
        pytest.skip(f"README.md line {line} needs {what}, which is not installed")
    except FileNotFoundError as exc:
        missing = Path(str(exc.filename or ""))
        if not (folder / missing.name).exists():
            pytest.skip(f"README.md line {line} needs the data file {exc.filename}")
        raise
    return namespace


@pytest.mark.parametrize(
    ("line", "code"), PYTHON_BLOCKS, ids=[f"line{line}" for line, _ in PYTHON_BLOCKS]
)
def test_python_block_runs(line: int, code: str, readme_dir: Path) -> None:
    _run_block(line, code, readme_dir)


def _calc_commands() -> list[tuple[int, list[str]]]:
    found = []
    for start, code in _blocks("bash"):
        for offset, text in enumerate(code.splitlines(), start=1):
            words = shlex.split(text, comments=True)
            if words[:2] == ["stereodepth", "calc"]:
                found.append((start + offset, words[1:]))
    return found


CALC_COMMANDS = _calc_commands()


def test_readme_has_calc_commands() -> None:
    assert len(CALC_COMMANDS) >= 2


@pytest.mark.parametrize(
    ("line", "argv"), CALC_COMMANDS, ids=[f"line{line}" for line, _ in CALC_COMMANDS]
)
def test_calc_command_runs(
    line: int, argv: list[str], readme_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from stereodepth import StereoRig
    from stereodepth.cli import main

    if "--plot" in argv and importlib.util.find_spec("matplotlib") is None:
        pytest.skip(f"README.md line {line} needs matplotlib (the plot extra)")
    assert main(argv) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    if "--json" not in argv:
        # the rig line is the Python call that builds the same rig
        shown = out.splitlines()[0].split(None, 1)[1]
        assert repr(eval(shown, {"StereoRig": StereoRig})) == shown
