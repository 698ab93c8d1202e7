"""stereodepth.calib: Middlebury calib.txt parsed exactly (line ends, spacing) or refused with
the file and the field named."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from stereodepth import StereoRig
from stereodepth.calib import read_middlebury_calib

# The layout of the 2014 files (values made up for the test).
CALIB = (
    "cam0=[3950.25 0 1180.5; 0 3950.25 1005.75; 0 0 1]\n"
    "cam1=[3950.25 0 1310.125; 0 3950.25 1005.75; 0 0 1]\n"
    "doffs=129.625\n"
    "baseline=190.5\n"
    "width=2900\n"
    "height=1950\n"
    "ndisp=280\n"
    "isint=0\n"
    "vmin=31\n"
    "vmax=257\n"
    "dyavg=0.918\n"
    "dymax=1.516\n"
)


def check(c: object) -> None:
    from stereodepth.calib import MiddleburyCalib

    assert isinstance(c, MiddleburyCalib)
    want0 = [[3950.25, 0, 1180.5], [0, 3950.25, 1005.75], [0, 0, 1]]
    np.testing.assert_array_equal(c.cam0, np.array(want0))
    assert c.cam1[0, 2] == 1310.125
    assert (c.doffs_px, c.baseline_mm, c.focal_px) == (129.625, 190.5, 3950.25)
    assert (c.width_px, c.height_px, c.ndisp) == (2900, 1950, 280)


@pytest.mark.parametrize(
    "transform",
    [
        lambda t: t,
        lambda t: t.replace("\n", "\r\n"),  # Windows
        lambda t: t.replace("\n", "\r"),  # old Mac
        lambda t: t.replace("=", " = ").replace("\n", " \t\n"),  # spaces around = and at ends
        lambda t: "\n" + t.replace("\n", "\n\n"),  # blank lines
        lambda t: "\ufeff" + t.replace("\n", "\r\n"),  # Notepad's byte-order mark
        lambda t: t.rstrip("\n"),  # no final line end
    ],
)
def test_layouts(tmp_path: Path, transform: Callable[[str], str]) -> None:
    p = tmp_path / "calib.txt"
    p.write_bytes(transform(CALIB).encode("utf-8"))
    check(read_middlebury_calib(p))
    rig = StereoRig.from_middlebury_calib(p)
    assert (rig.baseline_mm, rig.focal_px, rig.doffs_px) == (190.5, 3950.25, 129.625)


def test_minimal(tmp_path: Path) -> None:
    p = tmp_path / "calib.txt"
    p.write_text("cam0=[700 0 300; 0 700 200; 0 0 1]\nbaseline=160\n")
    c = read_middlebury_calib(p)
    np.testing.assert_array_equal(c.cam1, c.cam0)
    assert (c.doffs_px, c.width_px, c.height_px, c.ndisp) == (0.0, None, None, None)


@pytest.mark.parametrize(
    ("drop", "doffs"),
    [("cam1", 129.625), ("doffs", 129.625), ("nothing", 129.625)],
)
def test_doffs_and_cam1_give_each_other(tmp_path: Path, drop: str, doffs: float) -> None:
    """doffs is cam1's cx - cam0's cx: a file with only one of them gives the same rig to every
    reader (the rectifier once took doffs 0 from a file without cam1, the calculator 129.625)."""
    from stereodepth import StereoRectifier
    from stereodepth.calib import read_calibration, read_stereo_calibration

    p = tmp_path / "calib.txt"
    p.write_text(CALIB if drop == "nothing" else replace(drop, None))
    c = read_middlebury_calib(p)
    assert c.doffs_px == doffs and c.cam1[0, 2] - c.cam0[0, 2] == doffs
    rigs = [
        StereoRig.from_middlebury_calib(p),
        read_stereo_calibration(p).to_rig(),
        StereoRectifier.from_file(p).rig,
    ]
    assert [r.doffs_px for r in rigs] == [doffs] * 3
    assert read_calibration(p).doffs_px == doffs
    # within the files' three decimals, the two agree
    p.write_text(replace("doffs", "129.626"))
    assert read_middlebury_calib(p).doffs_px == 129.626


def replace(key: str, value: str | None) -> str:
    lines = [ln for ln in CALIB.splitlines() if not ln.startswith(key + "=")]
    if value is not None:
        lines.append(f"{key}={value}")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (replace("cam0", None), r"missing field 'cam0' in Middlebury calib\.txt"),
        (replace("baseline", None), r"missing field 'baseline'"),
        ("# a comment\n" + CALIB, r"line 1 of a Middlebury calib\.txt must be key=value, got '#"),
        (CALIB + "ndisp 280\n", r"line 13 of a Middlebury calib\.txt must be key=value"),
        (CALIB + "baseline=193\n", r"baseline is given twice \(line 13\)"),
        (replace("cam0", "[1 2 3]"), r"cam0 must be a 3x3 matrix \[fx 0 cx; 0 fy cy; 0 0 1\]"),
        (replace("cam0", "3950 0 1180; 0 3950 1005; 0 0 1"), r"cam0 must be a 3x3 matrix"),
        (replace("cam1", "[1 0 1; 0 1 1; 0 0 1; 0 0 0]"), r"cam1 must be a 3x3 matrix"),
        (replace("cam1", "[1 0 1 0; 0 1 1; 0 0 1]"), r"cam1 must be a 3x3 matrix"),
        (replace("cam0", "[f 0 1; 0 1 1; 0 0 1]"), r"cam0 must be a 3x3 matrix .* of numbers"),
        (replace("cam0", "[nan 0 1; 0 1 1; 0 0 1]"), r"cam0 must be a 3x3 matrix .* of numbers"),
        (replace("cam0", "[1e999 0 1; 0 1 1; 0 0 1]"), r"cam0 must be finite"),
        (replace("cam0", "[0 0 1; 0 1 1; 0 0 1]"), r"cam0 focal lengths must be > 0"),
        (replace("cam1", "[5 0 1; 0 -5 1; 0 0 1]"), r"cam1 focal lengths must be > 0"),
        (replace("cam0", "[5 0 1; 0 5 1; 0 0 2]"), r"cam0's last row must be 0 0 1"),
        # A skew, or a cam1 of another focal length or row, was ignored: not a rectified pair.
        (
            replace("cam0", "[3950.25 2 1180.5; 0 3950.25 1005.75; 0 0 1]"),
            r"cam0 must have no skew \(its \[0, 1\] entry 0\)",
        ),
        (
            replace("cam1", "[3990 0 1310.125; 0 3990 1005.75; 0 0 1]"),
            r"cam0 and cam1 are not a rectified pair: their focal length fx differ "
            r"\(3950\.25 and 3990\)",
        ),
        (
            replace("cam1", "[3950.25 0 1310.125; 0 3950.25 1015; 0 0 1]"),
            r"cam0 and cam1 are not a rectified pair: their cy differ \(1005\.75 and 1015\)",
        ),
        (replace("baseline", "0"), r"baseline must be > 0 mm, got '0'"),
        (replace("baseline", "-193"), r"baseline must be > 0 mm, got '-193'"),
        (replace("baseline", "193mm"), r"baseline must be a finite number, got '193mm'"),
        (replace("baseline", "inf"), r"baseline must be a finite number, got 'inf'"),
        (replace("baseline", "1e999"), r"baseline must be a finite number, got '1e999'"),
        (replace("doffs", "nan"), r"doffs must be a finite number, got 'nan'"),
        (replace("doffs", ""), r"doffs must be a finite number, got ''"),
        (
            replace("doffs", "50"),
            r"doffs must be cam1's cx - cam0's cx \(1310\.12 - 1180\.5 = 129\.625 px\), "
            "got '50'",
        ),
        # One without the other was dropped: a 1920 px file matched 640 px images unchecked.
        (replace("height", None), r"width and height go together, got width='2900' and no height"),
        (replace("width", None), r"width and height go together, got height='1950' and no width"),
        (replace("width", "0"), r"width must be a whole number > 0, got '0'"),
        (replace("height", "1950.5"), r"height must be a whole number > 0, got '1950\.5'"),
        (replace("ndisp", "-280"), r"ndisp must be a whole number > 0, got '-280'"),
        (replace("ndisp", "lots"), r"ndisp must be a whole number > 0, got 'lots'"),
        # int() refuses over 4300 digits, in a message naming neither the file nor the key
        (replace("width", "9" * 5000), r"width must be a whole number > 0, got 5000 digits"),
        (replace("ndisp", "1" * 4301), r"ndisp must be a whole number > 0, got 4301 digits"),
        # and a long value is shown shortened
        (replace("ndisp", "x" * 5000), r"ndisp must be a whole number > 0, got 'x{20,120}\.\.\."),
    ],
)
def test_rejects(tmp_path: Path, text: str, message: str) -> None:
    p = tmp_path / "calib.txt"
    p.write_text(text)
    with pytest.raises(ValueError, match=r"^\S*calib\.txt: " + message):
        read_middlebury_calib(p)


def test_rejects_binary_and_missing(tmp_path: Path) -> None:
    p = tmp_path / "calib.txt"
    p.write_bytes(b"cam0=[1 0 1; 0 1 1; 0 0 1]\nbaseline=\xff\xfe\n")
    with pytest.raises(ValueError, match=r"calib\.txt: not a text file \(Middlebury calib\.txt\)"):
        read_middlebury_calib(p)
    with pytest.raises(FileNotFoundError, match=r"Middlebury calib\.txt not found: .*nope\.txt"):
        read_middlebury_calib(tmp_path / "nope.txt")


@pytest.mark.parametrize(
    ("cams", "exc"), [("x", ValueError), ((2.0, 3), TypeError), ((1, 1), ValueError)]
)
def test_read_calibration_checks_cams_of_a_middlebury_file(
    tmp_path: Path, cams: object, exc: type
) -> None:
    # Ignored for a Middlebury file: bad cameras went through without a word.
    from stereodepth.calib import read_calibration

    p = tmp_path / "calib.txt"
    p.write_text(CALIB)
    with pytest.raises(exc, match=r"^cams must be"):
        read_calibration(p, cams)  # type: ignore[arg-type]
    assert read_calibration(p, (2, 3)).focal_px == 3950.25  # good ones: not its business


def test_read_calibration_refuses_a_huge_file_before_reading_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # It was read whole (decoded into memory) before the readers' size limit refused it.
    from stereodepth.calib import read_calibration
    from stereodepth.calib._common import MAX_FILE_BYTES

    p = tmp_path / "calib.txt"
    with p.open("wb") as f:
        f.truncate(MAX_FILE_BYTES + 1)  # sparse: no disk used

    def unread(*args: object, **kwargs: object) -> None:
        raise AssertionError("the file was read")

    monkeypatch.setattr(Path, "read_text", unread)
    monkeypatch.setattr(Path, "read_bytes", unread)
    with pytest.raises(ValueError, match=r"calib\.txt: \d+ bytes is too large"):
        read_calibration(p)
