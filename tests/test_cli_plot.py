"""``stereodepth calc --plot``: the two charts from the command line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stereodepth.cli import main

pytest.importorskip("matplotlib", reason="the plot extra is not installed")

ARM = ["--baseline-mm", "150", "--focal-mm", "6", "--pixel-um", "2.8", "--width-px", "1280"]


def test_plot_writes_the_charts_and_says_where(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "charts.png"
    assert (
        main(
            [
                "calc",
                *ARM,
                "--disparity-px",
                "250",
                "--subpixel-px",
                "0.25",
                "--max-disparity-px",
                "256",
                "--plot",
                str(out),
            ]
        )
        == 0
    )
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = capsys.readouterr().out
    assert "1.28571 m" in text
    assert text.rstrip().endswith(f"charts written to {out}")


def test_plot_with_json_keeps_stdout_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "charts.svg"
    assert main(["calc", *ARM, "--disparity-px", "35", "--json", "--plot", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["disparity_px"] == 35.0
    assert out.read_bytes().startswith(b"<?xml")


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("charts.txt", "--plot must name a .png, .svg or .pdf file, got"),
        ("missing/charts.png", "--plot: the folder "),
        # a folder named like a chart: the error named a temporary file, status 1
        ("folder.png", "--plot must name a file, got the folder "),
    ],
)
def test_bad_plot_path_is_one_line_and_status_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, message: str
) -> None:
    if name == "folder.png":
        (tmp_path / name).mkdir()
    assert main(["calc", *ARM, "--disparity-px", "250", "--plot", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"stereodepth calc: error: {message}")
    assert err.count("\n") == 1
    assert [p.name for p in tmp_path.iterdir()] == ([name] if name == "folder.png" else [])


def test_target_disparity_0_of_a_rig_with_doffs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Middlebury's Adirondack (doffs 53.271 px): disparity 0 is a finite depth, B*f / doffs =
    # 3.434 m, but the depth-vs-disparity chart's axis is logarithmic: --plot failed with
    # "stereodepth calc: error: math domain error", exit 2, writing no charts.
    rig = ["--baseline-mm", "176.252", "--focal-px", "1038.018", "--doffs-px", "53.271"]
    out = tmp_path / "charts.svg"
    assert main(["calc", *rig, "--disparity-px", "0", "--plot", str(out)]) == 0
    assert out.read_bytes().lstrip().startswith(b"<?xml")
    text = capsys.readouterr().out
    assert "3.43438 m" in text and f"charts written to {out}" in text


def test_negative_disparity_of_a_rig_with_doffs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Middlebury's Adirondack (doffs 53.271 px): a point 10 m away has disparity
    # 176.252e-3 * 1038.018 / 10 - 53.271 = -34.97 px. calc refused it ("--disparity-px must
    # be finite and >= 0"); now it answers 10 m, and the charts are drawn (the depth-vs-
    # disparity chart's log axis cannot show the negative target, as it cannot show 0).
    rig = ["--baseline-mm", "176.252", "--focal-px", "1038.018", "--doffs-px", "53.271"]
    d = 0.176252 * 1038.018 / 10 - 53.271
    out = tmp_path / "charts.svg"
    assert main(["calc", *rig, "--disparity-px", repr(d), "--plot", str(out)]) == 0
    assert out.read_bytes().lstrip().startswith(b"<?xml")
    assert "charts written to" in capsys.readouterr().out
    assert main(["calc", *rig, "--disparity-px", repr(d), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["disparity_px"] == d
    assert summary["depth_m"] == pytest.approx(10.0, rel=1e-12)
