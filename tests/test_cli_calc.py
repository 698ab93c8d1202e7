"""The calc subcommand, run as a user runs it: the installed console script."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest

from stereodepth import StereoRig
from stereodepth.cli import main

ARM = ["--baseline-mm", "150", "--focal-mm", "6", "--pixel-um", "2.8", "--width-px", "1280"]


def run(*args: str) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("stereodepth")
    cmd = [exe] if exe else [sys.executable, "-m", "stereodepth.cli"]
    return subprocess.run([*cmd, *args], capture_output=True, text=True, timeout=60)


def test_console_script_prints_results_and_table() -> None:
    r = run("calc", *ARM, "--disparity-px", "250")
    assert r.returncode == 0, r.stderr
    assert "1.28571 m" in r.stdout and "0.7 mm" in r.stdout
    assert "disparity_px" in r.stdout and "depth_resolution_m" in r.stdout


def test_json_output_equals_the_library(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calc", *ARM, "--disparity-px", "250", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in (
        "depth_m",
        "disparity_mm",
        "max_depth_m",
        "depth_resolution_m",
        "focal_px",
        "hfov_deg",
        "table",
    ):
        assert key in out
    rig = StereoRig(150, 6, 2.8, width_px=1280)
    assert out == json.loads(json.dumps(rig.summary(250)))
    assert out["depth_m"] == rig.depth_m(250)


def test_focal_px_replaces_focal_mm_and_pixel_um(capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        main(
            [
                "calc",
                "--baseline-mm",
                "537.166",
                "--focal-px",
                "718.856",
                "--disparity-px",
                "40",
                "--json",
            ]
        )
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    assert out["depth_m"] == pytest.approx(0.537166 * 718.856 / 40)
    assert out["disparity_mm"] is None and out["hfov_deg"] is None


def test_markdown_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calc", *ARM, "--markdown", "--table-disparities-px", "10", "20"]) == 0
    out = capsys.readouterr().out
    assert "| disparity_px | disparity_mm | depth_m |" in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["--baseline-mm", "-150", "--focal-mm", "6", "--pixel-um", "2.8"],
            "--baseline-mm must be a finite number > 0, got -150.0",
        ),
        (
            ["--baseline-mm", "150", "--focal-mm", "6", "--pixel-um", "0"],
            "--pixel-um must be a finite number > 0, got 0.0",
        ),
        (["--baseline-mm", "150", "--focal-mm", "6"], "give --focal-mm and --pixel-um"),
        (
            ["--baseline-mm", "150", "--focal-mm", "6", "--pixel-um", "2", "--focal-px", "9"],
            "not both",
        ),
        ([*ARM, "--disparity-px", "nan"], "--disparity-px must be finite and >= 0, got nan"),
        (
            [*ARM, "--subpixel-px", "-0.1"],
            "--subpixel-px must be the matcher's disparity step, a number > 0",
        ),
        # Results a double cannot hold were inf (null with --json) with status 0.
        (
            ["--baseline-mm", "1e300", "--focal-px", "1e5", "--disparity-px", "1e-300"],
            "--disparity-px must give a depth (B*f / (d + doffs), B*f = 1e+302 m*px) that a "
            "double can hold (it overflows to inf or rounds to 0), got 1e-300, which gives inf m",
        ),
        (
            ["--baseline-mm", "1e300", "--focal-px", "1e5", "--disparity-px", "1e-300", "--json"],
            "--disparity-px must give a depth",
        ),
        (
            ["--baseline-mm", "100", "--focal-px", "1000", "--disparity-px", "1e300"],
            "--disparity-px must give a depth resolution (depth 1e-298 m",
        ),
        (
            ["--baseline-mm", "100", "--focal-px", "1000", "--max-disparity-px", "1e-320"],
            "--max-disparity-px must give a depth",
        ),
        (
            ["--baseline-mm", "100", "--focal-px", "1e300", "--table-disparities-px", "1e-30"],
            "--table-disparities-px must give a depth",
        ),
        # A sub-pixel step that underflows or overflows the resolution named the disparity.
        (
            ["--baseline-mm", "100", "--focal-px", "1000", "--subpixel-px", "5e-324"],
            "--subpixel-px must give a depth resolution that a double can hold (it overflows to "
            "inf or rounds to 0; depth 6.25 m, B*f = 100.0 m*px), got 5e-324, which gives 0.0 m",
        ),
        (
            ["--baseline-mm", "100", "--focal-px", "1000", "--subpixel-px", "1e308"],
            "--subpixel-px must give a depth resolution that a double can hold",
        ),
        # A warning on stderr before the error line ("RuntimeWarning: overflow encountered in
        # add"): 1e308 + 1e308 px is beyond a double; the depth, 100 / inf, rounds to 0.
        (
            [
                "--baseline-mm",
                "100",
                "--focal-px",
                "1000",
                "--doffs-px",
                "1e308",
                "--disparity-px",
                "1e308",
            ],
            "--disparity-px (with --doffs-px 1e+308) must give a depth (B*f / (d + doffs), "
            "B*f = 100.0 m*px) that a double can hold (it overflows to inf or rounds to 0), got "
            "1e+308, which gives 0.0 m",
        ),
        # doffs alone: the default table's depth resolutions round to 0, and the message named
        # only "the table's disparity".
        (
            ["--baseline-mm", "100", "--focal-px", "700", "--doffs-px", "1e308"],
            "the table's disparity (with --doffs-px 1e+308) must give a depth resolution",
        ),
    ],
)
def test_bad_input_is_one_line_and_status_2(args: list[str], message: str) -> None:
    r = run("calc", *args)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("stereodepth calc: error: ")
    assert message in lines[0]
    assert r.stdout == ""


def test_huge_but_representable_results_are_printed(capsys: pytest.CaptureFixture[str]) -> None:
    # B*f = 1e302 m*px: the depth at 1 px is 1e302 m and its resolution Z**2 / (B*f) is 1e302
    # m too (by hand), but Z * Z overflowed first, and --json printed null.
    args = ["--baseline-mm", "1e300", "--focal-px", "1e5", "--disparity-px", "1", "--json"]
    assert main(["calc", *args]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["depth_m"] == pytest.approx(1e302, rel=1e-12)
    assert out["depth_resolution_m"] == pytest.approx(1e302, rel=1e-12)
    assert out["depth_resolution_exact_m"] == pytest.approx(1e302 - 1e302 / 2, rel=1e-12)
    assert out["table"][0]["depth_resolution_m"] == pytest.approx(1e302, rel=1e-12)


def test_doffs_near_minus_the_largest_double(capsys: pytest.CaptureFixture[str]) -> None:
    # Every default table disparity (1 to 256 px) is below -doffs = 1e308 px: the table's one
    # row was math.ceil(1e308), a Python int numpy stored as an object array: "the table's
    # disparity must be a real number or array, got ndarray with dtype object", exit 2.
    # By hand: d = 1e308 px with doffs -1e308 is d + doffs = 0, a point at infinity.
    args = ["--baseline-mm", "100", "--focal-px", "1000", "--doffs-px", "-1e308", "--json"]
    assert main(["calc", *args]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["table"] == [{"disparity_px": 1e308, "depth_m": None, "depth_resolution_m": None}]
    assert out["max_depth_m"] is None  # inf: 1 px is beyond infinity here


def test_unparseable_number_is_status_2() -> None:
    r = run("calc", "--baseline-mm", "abc", "--focal-mm", "6", "--pixel-um", "2")
    assert r.returncode == 2 and "invalid float value: 'abc'" in r.stderr


def test_plot_without_matplotlib_is_one_line_and_status_1(
    tmp_path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib fails
    out = tmp_path / "charts.png"
    argv = ["calc", "--baseline-mm", "150", "--focal-px", "2143", "--plot", str(out)]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert (
        err
        == 'stereodepth calc: error: the charts need matplotlib: pip install "stereodepth[plot]"\n'
    )
    assert not out.exists()


def test_a_reader_that_stops_early_is_no_error() -> None:
    # As `stereodepth calc ... | head -1`: the pipe closes after the first line.
    exe = shutil.which("stereodepth")
    cmd = [exe] if exe else [sys.executable, "-m", "stereodepth.cli"]
    argv = [*cmd, "calc", *ARM, "--disparity-px", "250", "--table-disparities-px"]
    argv += [str(d) for d in range(1, 4001)]  # more output than a pipe buffers
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
        assert proc.stdout is not None and proc.stderr is not None
        first = proc.stdout.readline()
        proc.stdout.close()
        err = proc.stderr.read().decode()
        proc.wait(timeout=60)
    assert first.startswith(b"rig")
    assert err == ""
    assert proc.returncode == 1


def test_python_dash_m_runs_the_command() -> None:
    argv = [sys.executable, "-m", "stereodepth", "calc", *ARM, "--disparity-px", "250", "--json"]
    r = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["depth_m"] == StereoRig(150, 6, 2.8, 1280).depth_m(250)
