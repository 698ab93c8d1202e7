"""Every error path of the command line: one line on stderr, exit status 2, no traceback.

The message names what the user typed (the option, its value) and never our internals (the
library's parameter names, a class's __init__, a temporary file).
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from stereodepth.cli import main

ARM = ["--baseline-mm", "150", "--focal-px", "700"]
HAS_CV2 = importlib.util.find_spec("cv2") is not None
HAS_WEB = all(importlib.util.find_spec(m) is not None for m in ("fastapi", "uvicorn"))
#: Words of our internals that a user never typed.
INTERNALS = ("__init__", "StereoMatcher", "BlockMatchOptions", "disparity_step_px", ".tmp")


def one_line_usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Runs ``main(argv)``; asserts exit status 2, nothing on stdout and one line on stderr,
    and returns stderr."""
    try:
        status = main(argv)
    except SystemExit as exc:  # argparse exits itself
        status = exc.code  # type: ignore[assignment]
    out, err = capsys.readouterr()
    assert status == 2, err
    assert out == ""
    assert len(err.splitlines()) == 1, err
    return err


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder that eval reads as holding one scene (the files are never opened)."""
    root = tmp_path_factory.mktemp("scenes")
    scene = root / "s1"
    scene.mkdir()
    for name in ("left.png", "right.png", "disp_gt.npy"):
        (scene / name).write_bytes(b"")
    return root


CASES: list[tuple[list[str], str]] = [
    # the top-level command
    ([], "stereodepth: error: the following arguments are required: COMMAND"),
    (["bogus"], "stereodepth: error: argument COMMAND: invalid choice: 'bogus'"),
    (["--bogus"], "stereodepth: error: "),
    # calc: argparse
    (["calc"], "the following arguments are required: --baseline-mm"),
    (["calc", "--baseline-mm", "x"], "argument --baseline-mm: invalid float value: 'x'"),
    (["calc", *ARM, "--bogus", "1"], "unrecognized arguments: --bogus 1"),
    (
        ["calc", *ARM, "--json", "--markdown"],
        "argument --markdown: not allowed with argument --json",
    ),
    (["calc", *ARM, "--width-px", "1.5"], "argument --width-px: invalid int value: '1.5'"),
    # calc: the rig
    (
        ["calc", "--baseline-mm", "-1", "--focal-px", "700"],
        "--baseline-mm must be a finite number > 0",
    ),
    (["calc", "--baseline-mm", "150", "--focal-mm", "6"], "give --focal-mm and --pixel-um"),
    (
        ["calc", "--baseline-mm", "150", "--focal-mm", "6", "--pixel-um", "0"],
        "--pixel-um must be a finite number > 0, got 0.0",
    ),
    (["calc", *ARM, "--focal-mm", "6", "--pixel-um", "2"], "not both"),
    (
        ["calc", "--baseline-mm", "150", "--focal-mm", "6", "--pixel-um", "2", "--doffs-px", "3"],
        "--doffs-px goes with --focal-px",
    ),
    (["calc", *ARM, "--width-px", "0"], "--width-px must be an integer >= 1, got 0"),
    (["calc", *ARM, "--focal-px", "1e-320"], "--focal-px"),
    # calc: the question
    (["calc", *ARM, "--subpixel-px", "0"], "--subpixel-px must be the matcher's disparity step"),
    (["calc", *ARM, "--subpixel-px", "nan"], "--subpixel-px must be"),
    (["calc", *ARM, "--disparity-px", "-1"], "--disparity-px must be finite and >= 0, got -1.0"),
    (["calc", *ARM, "--disparity-px", "nan"], "--disparity-px must be finite and >= 0, got nan"),
    (
        ["calc", *ARM, "--doffs-px", "-50", "--disparity-px", "10"],
        "--disparity-px must be finite and >= 50 (with --doffs-px -50, a disparity below 50 px "
        "puts the point behind the cameras), got 10.0",
    ),
    (["calc", *ARM, "--doffs-px", "-inf"], "--doffs-px must be finite, got -inf"),
    (["calc", *ARM, "--max-disparity-px", "0"], "--max-disparity-px must be a finite number > 0"),
    (["calc", *ARM, "--table-disparities-px", "4", "-1"], "--table-disparities-px must be"),
    (["calc", *ARM, "--plot", "charts.gif"], "--plot must name a .png, .svg or .pdf file"),
    (
        ["calc", *ARM, "--plot", "no/such/folder/c.png"],
        "--plot: the folder '" + os.path.abspath("no/such/folder") + "' does not exist",
    ),
    # eval: argparse
    (["eval"], "the following arguments are required: DIR"),
    (["eval", "{scenes}", "--json", "--markdown"], "argument --markdown: not allowed with"),
    (["eval", "{scenes}", "--option", "foo"], "argument --option: expected KEY=VALUE"),
    (["eval", "{scenes}", "--method", "bogus"], "argument --method: method must be one of"),
    (["eval", "{scenes}", "--best-by", "x"], "argument --best-by: invalid choice: 'x'"),
    (["eval", "{scenes}", "--repeat", "x"], "argument --repeat: invalid int value: 'x'"),
    (["eval", "{scenes}", "--bogus"], "unrecognized arguments: --bogus"),
    # eval: values
    (["eval", "no/such/dir"], "DIR must be a folder of scenes, got 'no/such/dir'"),
    (["eval", "{scenes}", "--scene", "zzz"], "--scene zzz matches no scene"),
    (["eval", "{scenes}", "--repeat", "0"], "--repeat must be an integer >= 1, got 0"),
    (["eval", "{scenes}", "--threads", "-1"], "--threads must be an integer >= 0"),
    (["eval", "{scenes}", "--num-disparities", "10"], "--num-disparities must be a positive"),
    (["eval", "{scenes}", "--option", "foo=1"], "--option foo: stereodepth's matcher has no"),
    (["eval", "{scenes}", "--option", "cost=bogus"], "--option cost=bogus: cost must be"),
    (["eval", "{scenes}", "--option", "subpixel=maybe"], "--option subpixel=maybe: subpixel"),
    (["eval", "{scenes}", "--option", "num_disparities=64"], "--option num_disparities: set"),
    (["eval", "{scenes}", "--option", "threads=2"], "--option threads: use --threads"),
    (
        ["eval", "{scenes}", "--method", "opencv-bm", "--option", "cost=sad"],
        "--option is for stereodepth.block_match",
    ),
    (["eval", "{scenes}", "--opencv-option", "a=1"], "--opencv-option needs an OpenCV method"),
    (["eval", "{scenes}", "--method", "opencv-bm:4"], "block size of opencv-bm must be an odd"),
    # serve: argparse
    (["serve", "--port", "x"], "argument --port: invalid int value: 'x'"),
    (["serve", "--bogus"], "unrecognized arguments: --bogus"),
    (["serve", "extra"], "unrecognized arguments: extra"),
]
if HAS_CV2:
    CASES += [
        (
            ["eval", "{scenes}", "--method", "opencv-bm", "--opencv-option", "min_disparity=16"],
            "--opencv-option min_disparity: eval searches from 0",
        ),
        (
            ["eval", "{scenes}", "--method", "opencv-bm", "--opencv-option", "nope=1"],
            "--opencv-option nope: no selected OpenCV matcher has setNope()",
        ),
    ]
if HAS_WEB:  # serve checks its socket after importing the web extra
    CASES += [
        (["serve", "--port", "70000"], "--port must be an integer from 0 to 65535, got 70000"),
        (["serve", "--port", "-1"], "--port must be an integer from 0 to 65535, got -1"),
    ]


@pytest.mark.parametrize(("argv", "message"), CASES, ids=[" ".join(a) or "-" for a, _ in CASES])
def test_error_is_one_line_status_2_no_traceback(
    argv: list[str], message: str, scenes: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = [a.replace("{scenes}", str(scenes)) for a in argv]
    err = one_line_usage_error(argv, capsys)
    lines = err.splitlines()
    prefix = (
        "stereodepth: error: "
        if not argv or argv[0].startswith("-") or argv[0] == "bogus"
        else (f"stereodepth {argv[0]}: error: ")
    )
    assert lines[0].startswith(prefix), lines[0]
    assert message in lines[0]
    assert "Traceback" not in err and "usage:" not in err
    assert not any(word in lines[0] for word in INTERNALS), lines[0]


def console_usage_error(argv: list[str], **env: str) -> subprocess.CompletedProcess[str]:
    """``python -m stereodepth`` run with ``argv`` (and ``env`` added to the environment);
    asserts exit status 2, nothing on stdout and one line on stderr, and returns the run."""
    r = subprocess.run(
        [sys.executable, "-m", "stereodepth", *argv],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env={**os.environ, **env},
    )
    assert r.returncode == 2, r.stderr
    assert r.stdout == ""
    assert len(r.stderr.splitlines()) == 1, r.stderr
    return r


@pytest.mark.parametrize(
    "argv",
    [
        ["calc", "--baseline-mm", "150", "--focal-px", "700", "--subpixel-px", "0"],
        ["calc", "--baseline-mm", "150"],
        ["nope"],
    ],
)
def test_console_command_prints_one_line(argv: list[str]) -> None:
    """The same through a real process: nothing but the one line reaches the terminal."""
    r = console_usage_error(argv)
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize(
    "argv", [["calc", "--baseline-mm", "150", "--focal-px", "700"], ["--help"], ["match", "--help"]]
)
def test_a_mistyped_isa_variable_is_one_line(argv: list[str]) -> None:
    # STEREODEPTH_ISA=avx3 (no such ISA): building the parser asks the core for the cores this
    # process may use (the --threads help of eval), and the core refuses the variable; every
    # command, --help included, ended in a 16-line traceback, exit status 1.
    r = console_usage_error(argv, STEREODEPTH_ISA="avx3")
    assert r.stderr.startswith("stereodepth: error: the environment variable STEREODEPTH_ISA ")
    assert r.stderr.rstrip().endswith("got 'avx3'")


def test_disparity_zero_is_inf_in_text_and_table_and_null_in_json(
    capsys: pytest.CaptureFixture[str],
) -> None:
    import json

    assert main(["calc", *ARM, "--disparity-px", "0", "--table-disparities-px", "0", "1"]) == 0
    text = capsys.readouterr().out
    rows = {line[:28].strip(): line[28:].strip() for line in text.splitlines()[:9]}
    assert rows["depth"] == "inf"
    assert rows["depth resolution (1 px)"] == "inf"
    assert rows["disparity on the sensor"] == "-"  # not applicable: no pixel size
    table = text.split("\n\n")[1].splitlines()
    assert table[2].split() == ["0", "inf", "inf"]
    assert main(["calc", *ARM, "--disparity-px", "0", "--table-disparities-px", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["depth_m"] is None and out["depth_resolution_m"] is None
    assert out["table"][0]["depth_m"] is None


def test_printed_rig_is_the_call_that_builds_it(capsys: pytest.CaptureFixture[str]) -> None:
    from stereodepth import StereoRig

    for argv in (
        [*ARM, "--doffs-px", "3", "--width-px", "640"],
        ["--baseline-mm", "150", "--focal-mm", "6", "--pixel-um", "2.8"],
    ):
        assert main(["calc", *argv]) == 0
        shown = capsys.readouterr().out.splitlines()[0].split(None, 1)[1]
        rig = eval(shown, {"StereoRig": StereoRig})  # our own repr
        assert repr(rig) == shown


@pytest.mark.parametrize("value", ["-1e3", "-1E+3", "-1000.0", "-1000"])
def test_negative_numbers_in_any_notation_are_values_not_options(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--doffs-px -1e3`` was refused as "expected one argument" (argparse's own rule knows
    -3 and -.5 but not exponents); without '=' it must mean what '--doffs-px=-1e3' means."""
    assert main(["calc", *ARM, "--doffs-px", value, "--disparity-px", "1500"]) == 0
    spaced = capsys.readouterr().out
    assert main(["calc", *ARM, f"--doffs-px={value}", "--disparity-px", "1500"]) == 0
    assert spaced == capsys.readouterr().out
    assert "doffs_px=-1000.0" in spaced


def test_write_ply_to_a_missing_folder_names_the_path(tmp_path: Path) -> None:
    import numpy as np

    from stereodepth import write_ply

    target = tmp_path / "missing" / "cloud.ply"
    with pytest.raises(FileNotFoundError) as info:
        write_ply(target, np.zeros((2, 3), np.float32))
    assert info.value.filename == str(target)
    assert "the folder" in str(info.value) and ".tmp" not in str(info.value)
    with pytest.raises(IsADirectoryError, match="over a folder"):
        write_ply(tmp_path, np.zeros((2, 3), np.float32))
    with pytest.raises(TypeError, match=r"path must be a str or os\.PathLike, got int 3"):
        write_ply(3, np.zeros((2, 3), np.float32))  # type: ignore[arg-type]
    assert list(tmp_path.iterdir()) == []


RIG_PX = ["--focal-px", "700", "--baseline-mm", "120", "--num-disparities", "16"]


def usage_error_beside_a_pair(
    argv: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> str:
    """Runs ``argv`` in ``tmp_path`` holding a small left.png and right.png; asserts a one-line
    usage error (status 2, nothing on stdout) that wrote nothing there, and returns it."""
    image = pytest.importorskip("PIL.Image")
    import numpy as np

    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (24, 40), dtype=np.uint8)
    image.fromarray(left).save(tmp_path / "left.png")
    image.fromarray(np.roll(left, -2, axis=1)).save(tmp_path / "right.png")
    before = sorted(p.name for p in tmp_path.iterdir())
    monkeypatch.chdir(tmp_path)
    err = one_line_usage_error(argv, capsys)
    assert err.splitlines() == [err.strip()], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    return err


EMPTY_PATH_CASES: list[tuple[list[str], str]] = [
    (["calc", *ARM, "--plot", ""], "--plot"),
    (["eval", ""], "DIR"),
    (["match", "", "right.png", *RIG_PX], "LEFT"),
    (["match", "left.png", "", *RIG_PX], "RIGHT"),
    (["match", "left.png", "right.png", *RIG_PX, "-o", ""], "-o/--out"),
    (["match", "left.png", "right.png", "--calib", ""], "--calib"),
    (["match", "left.png", "right.png", *RIG_PX, "--calib-right", ""], "--calib-right"),
    (["batch", "", "-o", "out", *RIG_PX], "INPUT"),
    (["batch", ".", "-o", "", *RIG_PX], "-o/--output"),
    (["batch", ".", "-o", "out", "--calib", ""], "--calib"),
    (["batch", ".", "-o", "out", *RIG_PX, "--report", ""], "--report"),
]


@pytest.mark.parametrize(
    ("argv", "argument"),
    EMPTY_PATH_CASES,
    ids=[f"{argv[0]} {argument}" for argv, argument in EMPTY_PATH_CASES],
)
def test_empty_path_is_a_usage_error_not_the_current_folder(
    argv: list[str],
    argument: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """pathlib reads "" as ".": ``batch "$IN" -o "$OUT"`` with a variable unset matched every
    pair under the current folder or wrote into it, ``eval ""`` scored it, ``calc --plot ""``
    wrote no charts without a word, and ``match L ""`` said "RIGHT: image is a folder, not a
    file: .". Now each is argparse's one line naming the argument, and nothing is written."""
    err = usage_error_beside_a_pair(argv, tmp_path, monkeypatch, capsys)
    assert f"argument {argument}: expected a path, got ''" in err


LONG_NAME = "x" * 256  # one byte more than a file name may be (NAME_MAX)
LONG_PATH_CASES: list[tuple[list[str], str]] = [
    (["calc", *ARM, "--plot", f"{LONG_NAME}.png"], "argument --plot: "),
    (["eval", LONG_NAME], "argument DIR: "),
    (["match", LONG_NAME, "right.png", *RIG_PX], "argument LEFT: "),
    (["match", "left.png", f"d/{LONG_NAME}/r.png", *RIG_PX], "argument RIGHT: "),
    (["match", "left.png", "right.png", "--calib", LONG_NAME], "argument --calib: "),
    (["match", "left.png", "right.png", *RIG_PX, "-o", f"{LONG_NAME}/"], "argument -o/--out: "),
    # a prefix that fits, whose output names do not: "prefix" + "disparity.pfm"
    (["match", "left.png", "right.png", *RIG_PX, "-o", "p" * 250], "--out: the name 'ppp"),
    (["batch", LONG_NAME, "-o", "out", *RIG_PX], "argument INPUT: "),
    (["batch", ".", "-o", "out", "--calib", LONG_NAME], "argument --calib: "),
]


@pytest.mark.parametrize(
    ("argv", "fragment"),
    LONG_PATH_CASES,
    ids=[f"{argv[0]} {fragment.split(':')[0]}" for argv, fragment in LONG_PATH_CASES],
)
def test_a_name_too_long_for_a_file_is_a_usage_error(
    argv: list[str],
    fragment: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Each was pathlib's "[Errno 36] File name too long: '<the whole name>'" with exit
    status 1, naming no argument (a match prefix only once the pair had been read)."""
    err = usage_error_beside_a_pair(argv, tmp_path, monkeypatch, capsys)
    assert fragment in err
    assert "bytes long, more than a file name may be (255 bytes)" in err
    assert "Errno" not in err


def test_python_m_stereodepth_cli_prints_one_line_for_a_subcommands_error(
    tmp_path: Path,
) -> None:
    """``python -m stereodepth.cli`` runs cli.py as __main__, a second copy of the module: a
    usage error raised by a subcommand's own module (here eval's up-front check of
    intensity_range against an 8-bit scene) is the package module's UsageError, which that
    copy did not catch (a traceback). It now runs the package's main."""
    np = pytest.importorskip("numpy")
    image = pytest.importorskip("PIL.Image")
    scene = tmp_path / "s1"
    scene.mkdir()
    grey = np.random.default_rng(3).integers(0, 256, (16, 40), dtype=np.uint8)
    image.fromarray(grey).save(scene / "left.png")
    image.fromarray(grey).save(scene / "right.png")
    np.save(scene / "disp_gt.npy", np.ones((16, 40), np.float32))
    argv = ["eval", str(tmp_path), "--method", "bm", "--option", "intensity_range=0,4095"]
    r = subprocess.run(
        [sys.executable, "-m", "stereodepth.cli", *argv],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env={**os.environ, "PYTHONPATH": str(Path(main.__code__.co_filename).parents[1])},
    )
    assert (r.returncode, r.stdout) == (2, ""), r.stderr
    assert len(r.stderr.splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.startswith("stereodepth eval: error: --option intensity_range=0,4095")
