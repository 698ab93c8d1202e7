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


PIXELS = ["--baseline-mm", "100", "--focal-px", "700"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        # was matplotlib's "Data cannot be log-scaled because all values are <= 0."
        (["--max-disparity-px", "1e-200"], "--max-disparity-px 1e-200 cannot be charted"),
        # these two printed numpy's "RuntimeWarning: overflow encountered in exp", status 0
        (["--disparity-px", "1e-150"], "--disparity-px 1e-150 cannot be charted"),
        (["--max-disparity-px", "1e300"], "--max-disparity-px 1e+300 cannot be charted"),
        (["--baseline-mm", "1e-200"], "cannot be charted"),
    ],
)
def test_values_the_charts_cannot_show_are_refused_for_plots_only(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    out = tmp_path / "k.svg"
    assert main(["calc", *PIXELS, *argv]) == 0  # the calculator takes them
    capsys.readouterr()
    assert main(["calc", *PIXELS, *argv, "--plot", str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("stereodepth calc: error: ") and captured.err.count("\n") == 1
    assert message in captured.err
    assert "from 1e-100 to 1e+100" in captured.err
    assert not out.exists()


def test_the_range_the_refusal_names_can_be_charted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "k.svg"
    for flag, bad in (("--max-disparity-px", "1e-200"), ("--disparity-px", "1e-150")):
        assert main(["calc", *PIXELS, flag, bad, "--plot", str(out)]) == 2
        err = capsys.readouterr().err
        low, high = err.split("can be from ")[1].split(" px")[0].split(" to ")
        for value in (float(low) * 1.001, float(high) / 1.001):
            assert main(["calc", *PIXELS, flag, repr(value), "--plot", str(out)]) == 0
            assert capsys.readouterr().err == ""


def test_a_read_only_plot_is_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Charts of an earlier run made read-only: a usage error naming --plot, as match's --out
    # and batch's --report give (it was exit 1 with the OS's "[Errno 13]"), the file kept.
    kept = tmp_path / "charts.png"
    kept.write_bytes(b"earlier charts")
    kept.chmod(0o444)
    try:
        code = main(["calc", *ARM, "--disparity-px", "250", "--plot", str(kept)])
    finally:
        kept.chmod(0o644)
    captured = capsys.readouterr()
    assert code == 2
    assert captured.out == ""
    assert captured.err.startswith(
        "stereodepth calc: error: --plot: cannot write charts.png: the file is read-only"
    )
    assert captured.err.count("\n") == 1
    assert "Errno" not in captured.err
    assert kept.read_bytes() == b"earlier charts"
