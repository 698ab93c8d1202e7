"""``stereodepth eval``'s OpenCV parameters checked before any scene runs: SGBM's block size
range-checked as opencv-bm's is (9999 was OpenCV's "integer won't fit into a C int"), and
every ``--opencv-option`` value against what OpenCV takes (``mode=99`` was taken without a
word; ``mode`` is now refused, as the method chooses it: ``mode=2`` ran SGBM, 3WAY and HH all
as 3WAY under their own names): one line naming the parameter, exit status 2, nothing on stdout."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cv2")
pytest.importorskip("PIL", reason="reading images needs Pillow (the batch extra)")

from PIL import Image

from stereodepth.cli import main


@pytest.fixture
def scenes(tmp_path: Path) -> Path:
    root = tmp_path / "scenes"
    scene = root / "s1"
    scene.mkdir(parents=True)
    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (64, 128), dtype=np.uint8)
    Image.fromarray(left).save(scene / "left.png")
    Image.fromarray(np.roll(left, -5, axis=1)).save(scene / "right.png")
    np.save(scene / "disp_gt.npy", np.full((64, 128), 5, np.float32))
    return root


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["eval", *argv])
    out, err = capsys.readouterr()
    return code, out, err


BAD = [
    (
        ["--method", "opencv-sgbm", "--block-size", "9999"],
        "block size of opencv-sgbm must be an odd integer in 1..8191",
    ),
    (
        ["--method", "opencv-sgbm-3way:8193"],
        "block size of opencv-sgbm-3way must be an odd integer in 1..8191",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "mode=99"],
        "--opencv-option mode=99: the method chooses OpenCV's SGBM mode",
    ),
    (
        ["--method", "opencv-bm", "opencv-sgbm-hh", "--opencv-option", "mode=-1"],
        "--opencv-option mode=-1: the method chooses",
    ),
    (
        # mode=2 ran every SGBM method as MODE_SGBM_3WAY under its own name
        [
            *("--method", "opencv-sgbm", "opencv-sgbm-3way", "opencv-sgbm-hh"),
            *("--opencv-option", "mode=2"),
        ],
        "--opencv-option mode=2: the method chooses OpenCV's SGBM mode: opencv-sgbm "
        "(MODE_SGBM), opencv-sgbm-hh (MODE_HH), opencv-sgbm-3way and opencv-sgbm-3way-padded "
        "(MODE_SGBM_3WAY); MODE_HH4 is not offered",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "mode=0x1"],
        "--opencv-option mode=0x1: the method chooses",
    ),
    (  # the key becomes setMode in any of these spellings: Mode=1 set it on every matcher
        ["--method", "opencv-sgbm", "opencv-sgbm-hh", "--opencv-option", "Mode=1"],
        "--opencv-option Mode=1: the method chooses",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "mode_=1"],
        "--opencv-option mode_=1: the method chooses",
    ),
    (
        ["--method", "opencv-bm", "--opencv-option", "pre_filter_type=5"],
        "pre_filter_type=5 rejected by opencv-bm: pre_filter_type must be 0",
    ),
    (
        ["--method", "opencv-bm", "--opencv-option", "pre_filter_size=4"],
        "pre_filter_size must be an odd integer in 5..255",
    ),
    (
        ["--method", "opencv-bm", "--opencv-option", "pre_filter_cap=64"],
        "pre_filter_cap=64 rejected by opencv-bm: pre_filter_cap must be an integer in 1..63",
    ),
    (
        ["--method", "opencv-bm", "opencv-sgbm", "--opencv-option", "texture_threshold=-1"],
        "texture_threshold=-1 rejected by opencv-bm",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "uniqueness_ratio=-1"],
        "uniqueness_ratio=-1 rejected by opencv-sgbm: uniqueness_ratio must be an integer in "
        "0..2147483647",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "uniqueness_ratio=1.5"],
        "uniqueness_ratio=1.5 rejected by opencv-sgbm",
    ),
    (
        ["--method", "opencv-bm", "--opencv-option", "speckle_range=99999999999"],
        "speckle_range=99999999999 rejected by opencv-bm: speckle_range must be an integer in "
        "0..2147483647",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "speckle_window_size=true"],
        "speckle_window_size=true rejected by opencv-sgbm",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "p1=0"],
        "p1=0 rejected by opencv-sgbm: p1 must be an integer in 1..2147483647",
    ),
    (  # the upper bound was left out: "p1 must be an integer >= 1"
        ["--method", "opencv-sgbm", "--opencv-option", "p1=100000000000"],
        "p1=100000000000 rejected by opencv-sgbm: p1 must be an integer in 1..2147483647",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "p2=2147483648"],
        "p2=2147483648 rejected by opencv-sgbm: p2 must be an integer in 1..2147483647",
    ),
    (
        ["--method", "opencv-bm", "--opencv-option", "texture_threshold=2147483648"],
        "texture_threshold must be an integer in 0..2147483647",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "p1=100", "--opencv-option", "p2=50"],
        "--opencv-option p2=50: OpenCV's P2 must be > P1, got p1=100 (OpenCV would use "
        "P2 = P1 + 1 instead)",
    ),
    # a p2 at or below eval's P1 (8 x 5 x 5 = 200 for block 5): OpenCV used 201 for all three
    *(
        (
            ["--method", "opencv-sgbm", "--opencv-option", f"p2={p2}"],
            f"--opencv-option p2={p2}: OpenCV's P2 must be > P1, and eval's P1 for "
            "opencv-sgbm:5 is 200 (8 x 5 x 5): give p1 too, or a larger p2",
        )
        for p2 in (1, 150, 200)
    ),
    (  # the block size whose P1 the p2 does not pass
        ["--method", "opencv-sgbm-3way:3,7", "--opencv-option", "p2=100"],
        "--opencv-option p2=100: OpenCV's P2 must be > P1, and eval's P1 for "
        "opencv-sgbm-3way:7 is 392 (8 x 7 x 7)",
    ),
    (  # a p1 at or above eval's P2 (32 x 5 x 5 = 800)
        ["--method", "opencv-sgbm", "--opencv-option", "p1=800"],
        "--opencv-option p1=800: OpenCV's P2 must be > P1, and eval's P2 for opencv-sgbm:5 "
        "is 800 (32 x 5 x 5): give p2 too, or a smaller p1",
    ),
    # the value as typed: it read p1=True and p1=(10, 'p2=5')
    (
        ["--method", "opencv-sgbm", "--opencv-option", "p1=TRUE"],
        "--opencv-option p1=TRUE rejected by opencv-sgbm: p1 must be an integer in ",
    ),
    (
        ["--method", "opencv-sgbm", "--opencv-option", "p1=10,p2=5"],
        "--opencv-option p1=10,p2=5 rejected by opencv-sgbm: p1 must be an integer in ",
    ),
]


@pytest.mark.parametrize(("argv", "message"), BAD)
def test_bad_opencv_parameters_one_line_exit_2(
    scenes: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    code, out, err = run(capsys, str(scenes), *argv, "--repeat", "1")
    assert (code, out) == (2, "")
    assert err.startswith("stereodepth eval: error: ") and err.count("\n") == 1
    assert message in err
    assert "C int" not in err or "P2 = 32" in err


@pytest.mark.parametrize(
    "argv",
    [
        ["--method", "opencv-sgbm:31"],
        ["--method", "opencv-bm", "--opencv-option", "pre_filter_type=1"],
        ["--method", "opencv-bm", "--opencv-option", "pre_filter_cap=63"],
        ["--method", "opencv-bm", "--opencv-option", "disp12_max_diff=-1"],
        ["--method", "opencv-sgbm", "--opencv-option", "p1=10", "--opencv-option", "p2=200"],
        ["--method", "opencv-sgbm", "--opencv-option", "p2=201"],
        ["--method", "opencv-sgbm", "--opencv-option", "p1=799"],
        ["--method", "opencv-bm", "opencv-sgbm", "--opencv-option", "texture_threshold=5"],
    ],
)
def test_good_opencv_parameters_run(
    scenes: Path, capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    code, out, err = run(capsys, str(scenes), *argv, "--repeat", "1", "--threads", "1")
    assert code == 0, err
    assert "s1" in out
