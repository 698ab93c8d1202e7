"""The KITTI calibration reader (stereodepth.calib.read_kitti_calib) parses exactly: LF, CR LF
or CR line ends, blank lines and trailing spaces are fine; the format has no comments, so
anything but ``NAME: values`` lines, a malformed matrix, a camera given twice or two cameras
that are not a rectified pair raise ValueError naming the file (and line) and what was wrong."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from stereodepth import batch, calib

F, CX, CY = 721.5377, 609.5593, 172.854
TX = {0: 0.0, 1: -387.5744, 2: 44.85728, 3: -339.5242}


def p_line(i: int, *, name: str = "P{i}", f: float = F, cy: float = CY) -> str:
    return (
        f"{name.format(i=i)}: {f:e} 0.000000e+00 {CX:e} {TX[i]:e} 0.000000e+00 {f:e} {cy:e} "
        "0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00"
    )


def kitti_2012() -> str:
    return "\n".join(p_line(i) for i in range(4)) + "\nTr: 1 0 0 0 0 1 0 0 0 0 1 0\n"


def write(tmp_path: Path, text: str, *, newline: str = "\n") -> Path:
    p = tmp_path / "000000.txt"
    p.write_bytes(text.replace("\n", newline).encode())
    return p


def test_reads_2012_and_2015_names(tmp_path: Path) -> None:
    c = calib.read_kitti_calib(write(tmp_path, kitti_2012()))
    assert (c.focal_px, c.cx_px, c.cy_px, c.doffs_px) == (F, CX, CY, 0.0)
    assert c.baseline_m == pytest.approx((TX[2] - TX[3]) / F)
    grey = calib.read_kitti_calib(write(tmp_path, kitti_2012()), (0, 1))
    assert grey.baseline_m == pytest.approx(387.5744 / F)
    rect = "calib_time: 09-Jan-2012 13:57:47\ncorner_dist: 9.950000e-02\n" + "\n".join(
        p_line(i, name="P_rect_0{i}") for i in range(4)
    )
    assert calib.read_kitti_calib(write(tmp_path, rect)) == c
    # still importable from stereodepth.batch, where it used to live
    assert batch.read_kitti_calib is calib.read_kitti_calib
    assert batch.read_calibration(write(tmp_path, rect)) == c


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"], ids=["LF", "CRLF", "CR"])
def test_line_ends_blank_lines_and_trailing_spaces(tmp_path: Path, newline: str) -> None:
    want = calib.read_kitti_calib(write(tmp_path, kitti_2012()))
    text = "\n" + "\n\n".join(line + " \t" for line in kitti_2012().splitlines()) + "\n\n"
    p = write(tmp_path, text, newline=newline)
    assert calib.read_kitti_calib(p) == want
    assert calib.read_calibration(p) == want


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("# KITTI\n" + kitti_2012(), r"000000.txt:1: expected 'NAME: values', got '# KITTI'"),
        (kitti_2012() + "P2 1 2 3\n", r":6: expected 'NAME: values', got 'P2 1 2 3'"),
        (kitti_2012().replace(p_line(3), "P3: 1 2 3"), r":4: P3 must be 12 numbers, got 3"),
        (kitti_2012().replace(p_line(3), p_line(3) + " 0"), r":4: P3 must be 12 numbers, got 13"),
        (
            kitti_2012().replace(p_line(3), p_line(3).replace("1.000000e+00", "nan")),
            r":4: P3 must be 12 finite numbers",
        ),
        (
            kitti_2012().replace(p_line(3), p_line(3).replace("1.000000e+00", "one")),
            r":4: P3 must be 12 numbers, got '7",
        ),
        (kitti_2012() + p_line(2, name="P_rect_0{i}") + "\n", r":6: P_rect_02 gives camera 2 "),
        (kitti_2012().replace("P3:", "Q3:"), r"000000.txt: missing P3 \(or P_rect_03\)"),
        (
            kitti_2012().replace(p_line(3), p_line(3, f=700.0)),
            r"P2 and P3 are not a rectified pair: their focal length fx differ",
        ),
        (
            kitti_2012().replace(p_line(3), p_line(3, cy=180.0)),
            r"P2 and P3 are not a rectified pair: their principal point row cy differ",
        ),
    ],
    ids=["comment", "no-colon", "short", "long", "nan", "word", "twice", "missing", "focal", "row"],
)
def test_inconsistent_files_are_refused(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        calib.read_kitti_calib(write(tmp_path, text))


def test_the_right_camera_must_be_right_of_the_left(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="camera 2 must be right of camera 3"):
        calib.read_kitti_calib(write(tmp_path, kitti_2012()), (3, 2))
    with pytest.raises(ValueError, match=r"cams must be two different KITTI cameras, got \(2, 2\)"):
        calib.read_kitti_calib(write(tmp_path, kitti_2012()), (2, 2))


@pytest.mark.parametrize(
    ("cams", "exc", "message"),
    [
        ((2,), ValueError, r"cams must be two camera numbers, got \(2,\)"),
        ((2.0, 3), TypeError, r"cams must be two whole numbers >= 0, got \(2\.0, 3\) \(a float\)"),
        ((-1, 3), ValueError, r"cams must be two whole numbers >= 0, got \(-1, 3\)"),
        (("2", "3"), TypeError, r"cams must be two whole numbers >= 0, got \('2', '3'\) \(a str\)"),
    ],
)
def test_cams_are_checked(tmp_path: Path, cams: Any, exc: type, message: str) -> None:
    # cams (2,) was Python's "not enough values to unpack (expected 2, got 1)", naming
    # nothing; (2.0, 3) and (-1, 3) were looked up as keys P2.0 and P-1 ("missing P2.0 (or
    # P_rect_02.0)"). They are checked as read_kitti_stereo_calibration's cameras are.
    with pytest.raises(exc, match=message):
        calib.read_kitti_calib(write(tmp_path, kitti_2012()), cams)
    assert calib.read_kitti_calib(write(tmp_path, kitti_2012()), (np.int64(2), 3)).focal_px > 0


def test_the_rectified_size_is_the_calibrations_image_size(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """calib_cam_to_cam.txt's S_rect_0i is the size of the rectified images: read_kitti_calib
    left it out, so `stereodepth match` (and batch) matched images of another size, e.g.
    downscaled ones, with depths off by the scale factor and no word; Middlebury's width
    and height were checked so already."""
    sizes = "S_rect_02: 1.242000e+03 3.750000e+02\nS_rect_03: 1.242000e+03 3.750000e+02\n"
    path = write(tmp_path, kitti_2012() + sizes)
    assert calib.read_kitti_calib(path).image_size == (1242, 375)
    assert calib.read_calibration(path).image_size == (1242, 375)
    assert calib.read_kitti_calib(write(tmp_path, kitti_2012())).image_size is None
    path = write(tmp_path, kitti_2012() + "S_rect_02: 1242 -375\n")
    with pytest.raises(ValueError, match=r"000000\.txt: S_rect_02 must be two whole numbers > 0"):
        calib.read_kitti_calib(path)

    pytest.importorskip("PIL", reason="reading images needs Pillow")
    import numpy as np
    from PIL import Image

    from stereodepth.cli import main

    path = write(tmp_path, kitti_2012() + sizes)
    img = np.zeros((188, 621), np.uint8)
    Image.fromarray(img).save(tmp_path / "l.png")
    Image.fromarray(img).save(tmp_path / "r.png")
    args = [str(tmp_path / n) for n in ("l.png", "r.png")] + ["--calib", str(path)]
    assert main(["match", *args, "-o", str(tmp_path / "o-"), "--no-preview"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "must have the size of the calibration in --calib, 1242x375 px, got 621x188" in err


_OPENCV_P = (
    "   rows: 3\n   cols: 4\n   dt: d\n"
    "   data: [ 700., 0., 320., {tx}, 0., 700., 240., 0., 0., 0., 1., 0. ]\n"
)


@pytest.mark.parametrize(
    "text",
    [
        # cv2.FileStorage's YAML of stereoRectify's P1 and P2: its "P1:" lines were read as
        # KITTI's ("expected 'NAME: values', got '%YAML 1.2'")
        "%YAML 1.2\n---\nP1: !!opencv-matrix\n"
        + _OPENCV_P.format(tx="0.")
        + "P2: !!opencv-matrix\n"
        + _OPENCV_P.format(tx="-84."),
        # its Q alone, and the older %YAML:1.0 header: read as a Middlebury calib.txt
        "%YAML:1.0\nQ: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n"
        "   data: [ 1., 0., 0., -320., 0., 1., 0., -240., 0., 0., 0., 700., 0., 0., 8.3, 0. ]\n",
        '<?xml version="1.0"?>\n<opencv_storage>\n<P2 type_id="opencv-matrix"><rows>3</rows>'
        "<cols>4</cols><dt>d</dt><data>700. 0. 320. -84. 0. 700. 240. 0. 0. 0. 1. 0.</data>"
        "</P2>\n</opencv_storage>\n",
        '{\n    "P2": {\n        "type_id": "opencv-matrix",\n        "rows": 3,'
        '\n        "cols": 4,\n        "dt": "d",\n        "data": [ 700.0, 0.0, 320.0,'
        " -84.0, 0.0, 700.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0 ]\n    }\n}\n",
    ],
    ids=["yaml-p1-p2", "yaml-q", "xml", "json"],
)
def test_read_calibration_names_an_opencv_file_for_what_it_is(tmp_path: Path, text: str) -> None:
    p = tmp_path / "stereo.yml"
    p.write_text(text)
    with pytest.raises(ValueError, match="an OpenCV FileStorage file") as e:
        calib.read_calibration(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: an OpenCV FileStorage file, not the calibration of a"), msg
    assert "read_stereo_calibration" in msg and "\n" not in msg


def test_read_calibration_tells_opencv_files_by_their_form_not_by_a_word(tmp_path: Path) -> None:
    # A KITTI file that mentions "!!opencv-matrix" in a note is a KITTI file (it was refused as
    # OpenCV's, while rectified_format called it KITTI); a file that merely starts with "{" or
    # "%YAML" in prose keeps the Middlebury reader's message.
    kitti = tmp_path / "calib.txt"
    kitti.write_text(kitti_2012() + "note: converted from a !!opencv-matrix by hand\n")
    assert calib.rectified_format(kitti) == "kitti"
    assert calib.read_calibration(kitti).focal_px == pytest.approx(F)
    for text in ['{"cam0": "[1 0 0; 0 1 0; 0 0 1]"}\n', "%YAML-ish notes\ncam0=[1 0 0]\n"]:
        other = tmp_path / "other.txt"
        other.write_text(text)
        with pytest.raises(ValueError, match="Middlebury") as e:
            calib.read_calibration(other)
        assert "OpenCV" not in str(e.value)
