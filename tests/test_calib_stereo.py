"""stereodepth.calib.StereoCalibration and its readers: OpenCV FileStorage YAML and XML, ROS
camera_info pairs, Kalibr camchains, Middlebury calib.txt and KITTI files, each with fixtures
written here, and every malformed file refused with the file and the key named."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from stereodepth import StereoRig
from stereodepth import calib as sc
from stereodepth.calib import StereoCalibration, read_stereo_calibration

pytest.importorskip("yaml", reason="PyYAML (the calib extra) is not installed")


def rot(rx: float, ry: float, rz: float) -> np.ndarray:
    """A rotation matrix from small angles (radians), x then y then z."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return mz @ my @ mx


K1 = np.array([[700.0, 0.0, 320.5], [0.0, 705.0, 240.25], [0.0, 0.0, 1.0]])
K2 = np.array([[710.0, 0.0, 330.0], [0.0, 712.0, 236.0], [0.0, 0.0, 1.0]])
D1 = np.array([0.1, -0.2, 0.001, 0.002, 0.03])
D2 = np.array([0.09, -0.15, 0.0, 0.001, 0.01])
R = rot(0.01, -0.02, 0.005)
T_MM = np.array([-120.0, 1.0, 0.5])  # as OpenCV gives it for a target measured in mm


def number(v: float) -> str:
    """As OpenCV writes a double: full precision, .Nan and .Inf for the special values."""
    special = {"nan": ".Nan", "inf": ".Inf", "-inf": "-.Inf"}
    return special.get(repr(float(v)), repr(float(v)))


def fmt(a: Any) -> str:
    return ", ".join(number(v) for v in np.asarray(a, dtype=np.float64).reshape(-1))


def opencv_yaml(entries: dict[str, Any], header: str = "%YAML:1.0\n---\n") -> str:
    """A FileStorage YAML file as OpenCV 4 writes it (matrices as !!opencv-matrix)."""
    out = [header.rstrip("\n")] if header else []
    for key, value in entries.items():
        if isinstance(value, np.ndarray):
            m = value if value.ndim == 2 else value.reshape(1, -1)
            out += [
                f"{key}: !!opencv-matrix",
                f"   rows: {m.shape[0]}",
                f"   cols: {m.shape[1]}",
                "   dt: d",
                f"   data: [ {fmt(m)} ]",
            ]
        else:
            out.append(f"{key}: {value}")
    return "\n".join(out) + "\n"


def opencv_xml(entries: dict[str, Any]) -> str:
    out = ['<?xml version="1.0"?>', "<opencv_storage>"]
    for key, value in entries.items():
        if isinstance(value, np.ndarray):
            m = value if value.ndim == 2 else value.reshape(1, -1)
            data = " ".join(number(v) for v in m.reshape(-1))
            out.append(
                f'<{key} type_id="opencv-matrix"><rows>{m.shape[0]}</rows><cols>{m.shape[1]}'
                f"</cols><dt>d</dt><data>\n    {data}</data></{key}>"
            )
        else:
            out.append(f"<{key}>{value}</{key}>")
    return "\n".join([*out, "</opencv_storage>"]) + "\n"


def stereo_entries(**changes: Any) -> dict[str, Any]:
    e: dict[str, Any] = {
        "M1": K1,
        "D1": D1,
        "M2": K2,
        "D2": D2,
        "R": R,
        "T": T_MM.reshape(3, 1),
        "image_width": 640,
        "image_height": 480,
    }
    for k, v in changes.items():
        if v is None:
            e.pop(k, None)
        else:
            e[k] = v
    return e


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# --- OpenCV FileStorage -----------------------------------------------------------------------
@pytest.mark.parametrize("ext", ["yml", "xml", "json"])
def test_opencv_written_by_cv2(tmp_path: Path, ext: str) -> None:
    """Files written by the real cv2.FileStorage after cv2.stereoRectify, in its three formats
    (its JSON's matrices, objects with "type_id": "opencv-matrix", were once refused)."""
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(K1, D1, K2, D2, (640, 480), R, T_MM.reshape(3, 1))
    path = tmp_path / f"stereo.{ext}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in {
        "M1": K1,
        "D1": D1.reshape(1, 5),
        "M2": K2,
        "D2": D2.reshape(1, 5),
        "R": R,
        "T": T_MM.reshape(3, 1),
        "R1": r1,
        "R2": r2,
        "P1": p1,
        "P2": p2,
        "Q": q,
    }.items():
        fs.write(key, value)
    fs.write("imageSize", (640, 480))
    fs.release()
    c = read_stereo_calibration(path, translation_unit="mm")
    assert isinstance(c, StereoCalibration)
    np.testing.assert_array_equal(c.K1, K1)
    np.testing.assert_array_equal(c.K2, K2)
    np.testing.assert_array_equal(c.D1, D1)
    np.testing.assert_array_equal(c.D2, D2)
    np.testing.assert_array_equal(c.R, R)
    np.testing.assert_allclose(c.T, T_MM / 1000, rtol=1e-15)
    assert c.distortion_model == "plumb_bob" and c.image_size == (640, 480)
    assert not c.rectified and c.source == str(path)
    np.testing.assert_array_equal(c.R1, r1)
    np.testing.assert_array_equal(c.R2, r2)
    np.testing.assert_array_equal(c.P1, p1)
    np.testing.assert_allclose(c.P2[:, 3], p2[:, 3] / 1000, rtol=1e-15)
    # Q in metres: the same points as OpenCV's, a thousand times smaller
    disp = np.array([[10.0, 20.5], [33.0, 64.0]], np.float32)
    want = cv2.reprojectImageTo3D(disp, q) / 1000
    np.testing.assert_allclose(cv2.reprojectImageTo3D(disp, c.Q), want, rtol=1e-6)
    # the rig of the rectified pair: P's focal length, the baseline |T| in mm
    rig = c.to_rig()
    assert rig.focal_px == p1[0, 0] and rig.width_px == 640 and rig.height_px == 480
    assert rig.baseline_mm == pytest.approx(np.linalg.norm(T_MM), rel=1e-12)
    assert rig.doffs_px == p2[0, 2] - p1[0, 2]
    for func in (sc.read_opencv_stereo_calibration,):
        c2 = func(path, translation_unit="mm")
        np.testing.assert_array_equal(c2.T, c.T)


def test_opencv_fisheye_written_by_cv2(tmp_path: Path) -> None:
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    d = np.array([[0.01], [-0.002], [0.0003], [-0.00004]])
    fs = cv2.FileStorage(str(tmp_path / "f.yaml"), cv2.FILE_STORAGE_WRITE)
    for key, value in {"K1": K1, "D1": d, "K2": K2, "D2": d, "R": R, "T": T_MM / 1000}.items():
        fs.write(key, value)
    fs.write("distortion_model", "fisheye")
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.release()
    c = read_stereo_calibration(tmp_path / "f.yaml")
    assert c.distortion_model == "equidistant"
    np.testing.assert_array_equal(c.D1, d.reshape(4))
    np.testing.assert_allclose(c.T, T_MM / 1000, rtol=1e-15)
    with pytest.raises(ValueError, match=r"f\.yaml: distortion_model is 'equidistant', "):
        read_stereo_calibration(tmp_path / "f.yaml", distortion_model="plumb_bob")


@pytest.mark.parametrize("header", ["%YAML:1.0\n---\n", "%YAML:1.0\n", "%YAML 1.2\n---\n", ""])
def test_opencv_yaml_layouts(tmp_path: Path, header: str) -> None:
    """OpenCV 4's %YAML:1.0 (that plain YAML parsers reject), OpenCV 5's %YAML 1.2, none;
    CR LF line ends; image size as a sequence."""
    entries = stereo_entries(image_width=None, image_height=None, imageSize="[ 640, 480 ]")
    text = opencv_yaml(entries, header).replace("\n", "\r\n")
    c = read_stereo_calibration(write(tmp_path / "s.yml", text), translation_unit="m")
    np.testing.assert_array_equal(c.K1, K1)
    np.testing.assert_array_equal(c.T, T_MM)  # translation_unit "m": taken as it is
    assert c.image_size == (640, 480) and c.R1 is None and c.Q is None


def test_opencv_translation_unit_not_given_refuses_an_implausible_baseline(
    tmp_path: Path,
) -> None:
    """OpenCV files do not record T's unit. A T in millimetres read as metres (the default)
    would make every depth 1000 times too large: without a unit, a baseline above 10 m is
    refused with the way out; given a unit, any length is taken."""
    mm = write(tmp_path / "mm.yml", opencv_yaml(stereo_entries()))  # |T| = 120 (mm)
    with pytest.raises(
        ValueError,
        match=r"mm\.yml: T is 120\.0\d* long: .*give its unit with translation_unit, "
        r"e\.g\. 'mm', or 'm'",
    ):
        read_stereo_calibration(mm)
    np.testing.assert_allclose(read_stereo_calibration(mm, translation_unit="mm").T, T_MM / 1000)
    np.testing.assert_array_equal(read_stereo_calibration(mm, translation_unit="m").T, T_MM)
    metres = write(tmp_path / "m.yml", opencv_yaml(stereo_entries(T=T_MM.reshape(3, 1) / 1000)))
    np.testing.assert_allclose(read_stereo_calibration(metres).T, T_MM / 1000, rtol=1e-15)


def test_opencv_xml_by_hand(tmp_path: Path) -> None:
    c = read_stereo_calibration(
        write(tmp_path / "s.xml", opencv_xml(stereo_entries())), translation_unit="mm"
    )
    np.testing.assert_array_equal(c.D2, D2)
    np.testing.assert_array_equal(c.R, R)
    assert c.image_size == (640, 480)


def test_opencv_split_files_and_units(tmp_path: Path) -> None:
    """OpenCV's stereo_calib sample: intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml."""
    e = stereo_entries()
    intr = write(
        tmp_path / "intrinsics.yml", opencv_yaml({k: e[k] for k in ("M1", "D1", "M2", "D2")})
    )
    extr = write(tmp_path / "extrinsics.yml", opencv_yaml({k: e[k] for k in ("R", "T")}))
    for unit, scale in (("mm", 1e-3), ("cm", 1e-2), ("m", 1.0), ("in", 0.0254)):
        c = read_stereo_calibration(
            intr, second_path=extr, translation_unit=unit, image_size=(640, 480)
        )
        np.testing.assert_allclose(c.T, T_MM * scale, rtol=1e-15)
    assert c.source == f"{intr} + {extr}"
    c = read_stereo_calibration(
        extr, second_path=intr, image_size=(640, 480), translation_unit="mm"
    )  # either order
    np.testing.assert_array_equal(c.K1, K1)
    with pytest.raises(ValueError, match=r"intrinsics\.yml \+ .*extrinsics\.yml: no image size"):
        read_stereo_calibration(intr, second_path=extr, translation_unit="mm")
    with pytest.raises(ValueError, match=r"translation_unit must be one of 'm', .* got 'km'"):
        read_stereo_calibration(
            intr, second_path=extr, translation_unit="km", image_size=(640, 480)
        )
    write(tmp_path / "both.yml", opencv_yaml({"R": R}))
    with pytest.raises(ValueError, match=r"both\.yml: R is also given in .*extrinsics\.yml"):
        sc.read_opencv_stereo_calibration(extr, tmp_path / "both.yml", translation_unit="mm")


def test_opencv_distortion_forms(tmp_path: Path) -> None:
    d8 = np.array([0.1, -0.2, 0.001, 0.002, 0.03, 0.01, 0.0, 0.002])
    d14 = np.concatenate([d8, np.zeros(6)])
    for d, want in ((d8, d8), (d14, d8)):
        c = read_stereo_calibration(
            write(tmp_path / "d.yml", opencv_yaml(stereo_entries(D1=d, D2=d))),
            translation_unit="mm",
        )
        np.testing.assert_array_equal(c.D1, want)
    four = write(tmp_path / "f.yml", opencv_yaml(stereo_entries(D1=D1[:4], D2=D2[:4])))
    for model in ("equidistant", "plumb_bob"):
        c = read_stereo_calibration(four, distortion_model=model, translation_unit="mm")
        assert c.distortion_model == model
        np.testing.assert_array_equal(c.D1, D1[:4])
    # Four coefficients without a model are OpenCV's fisheye k1..k4 as often as plumb_bob's
    # k1 k2 p1 p2 (cv2.fisheye gives 4, cv2.stereoCalibrate 5 or more): they were read as the
    # latter, and a fisheye pair was rectified wrongly without a word.
    with pytest.raises(ValueError, match=r"f\.yml: D1 has 4 coefficients, which both OpenCV's"):
        read_stereo_calibration(four, translation_unit="mm")
    text = opencv_yaml(stereo_entries(D1=D1[:4], D2=D2[:4])) + "distortion_model: plumb_bob\n"
    c = read_stereo_calibration(write(tmp_path / "g.yml", text), translation_unit="mm")
    assert c.distortion_model == "plumb_bob"


NOT_ROTATION = r"must be a rotation \(R R\^T = I and det R = \+1 within 1e-05\)"


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"M2": None}, r"missing key K2 or M2 or cameraMatrix2"),
        ({"T": None}, r"missing key T"),
        ({"K1": K1}, r"both K1 and M1 are given"),
        ({"R": R * 1.001}, "R " + NOT_ROTATION + r", got max \|R R\^T - I\| = 0\.002"),
        ({"R": R @ np.diag([1.0, 1.0, -1.0])}, "R " + NOT_ROTATION + r".*det R = -1"),
        ({"R": R + 1e-5}, "R " + NOT_ROTATION),
        ({"R1": np.eye(3) * 2}, "R1 " + NOT_ROTATION),
        ({"R": R[:2]}, r"R must have shape \(3, 3\), got \(2, 3\)"),
        ({"T": np.array([[1.0, 2.0]])}, r"T must have shape \(3,\), got \(2,\)"),
        ({"T": np.zeros((3, 1))}, r"T must not be zero"),
        ({"P1": np.eye(3)}, r"P1 must have shape \(3, 4\), got \(3, 3\)"),
        ({"Q": np.eye(3)}, r"Q must have shape \(4, 4\), got \(3, 3\)"),
        ({"M1": np.full((3, 3), np.nan)}, r"M1 must be finite"),
        ({"D2": np.array([0.1, np.inf, 0, 0, 0])}, r"D2 must be finite"),
        ({"M1": np.diag([0.0, 700.0, 1.0])}, r"M1 focal lengths must be > 0, got fx=0\.0"),
        ({"M2": K2 * 2}, r"M2 must be \[fx s cx; 0 fy cy; 0 0 1\]"),
        ({"D1": D1[:3]}, r"D1 has 3 coefficients; the plumb_bob model takes 4 or 5 or 8"),
        ({"D1": np.zeros(6)}, r"D1 has 6 coefficients"),
        ({"D1": np.arange(14.0)}, r"D1 has thin prism or tilt terms \(coefficients 9 to 14\)"),
        ({"D1": np.zeros((2, 5))}, r"D1 must have shape \(n,\), got \(2, 5\)"),
        ({"distortion_model": "fov"}, r"distortion_model must be one of .* got 'fov'"),
        ({"distortion_model": "equidistant"}, r"D1 has 5 coefficients; the equidistant model"),
        ({"image_width": 0}, r"image_width, image_height must be two whole numbers > 0"),
        ({"image_width": 640.5}, r"image_width, image_height must be two whole numbers > 0"),
        ({"image_height": None}, r"image_width and image_height go together"),
        # The rectifier's limit, with the file and the key (it named neither).
        (
            {"image_width": 10**20},
            r"image_width, image_height must be at most 32000 x 32000 pixels, got "
            r"\(100000000000000000000, 480\)",
        ),
        ({"image_height": 32001}, r"image_width, image_height must be at most 32000 x 32000"),
        ({"imageSize": "[ 640 ]"}, r"imageSize must be \(width, height\), got \[640\]"),
        (
            {"image_width": "wide"},
            r"image_width, image_height must be two whole numbers > 0, got \('wide', 480\)",
        ),
    ],
)
@pytest.mark.parametrize("fmt_", ["yml", "xml"])
def test_opencv_rejects(tmp_path: Path, changes: dict[str, Any], message: str, fmt_: str) -> None:
    entries = stereo_entries(**changes)
    text = opencv_yaml(entries) if fmt_ == "yml" else opencv_xml(entries)
    path = write(tmp_path / f"bad.{fmt_}", text)
    if fmt_ == "xml" and "imageSize" in changes:
        path.write_text(text.replace("[ 640 ]", "640"))
        message = message.replace(r"\[640\]", "640")
    with pytest.raises(ValueError, match=r"^\S*bad\." + fmt_ + ": " + message):
        read_stereo_calibration(path, translation_unit="mm")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "%YAML:1.0\nM1: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1, 2 ]\n",
            r"M1: opencv-matrix of 3x3 needs 9 values, got 2",
        ),
        (
            "%YAML:1.0\nM1: !!opencv-matrix\n   rows: 1\n   cols: 1\n   dt: q\n   data: [ 1 ]\n",
            r"M1: opencv-matrix dt must be a type such as 'd' or 'f', got 'q'",
        ),
        (
            "%YAML:1.0\nM1: !!opencv-matrix\n   rows: 1\n   cols: 1\n   dt: d\n   data: [ x ]\n",
            r"M1: opencv-matrix data must be numbers, got 'x'",
        ),
        (
            "%YAML:1.0\nM1: !!opencv-matrix\n   rows: -1\n   cols: 1\n   dt: d\n   data: [ 1 ]\n",
            r"M1: opencv-matrix rows must be whole numbers >= 0, got -1",
        ),
        (
            "%YAML:1.0\nM1: !!opencv-matrix\n   cols: 1\n   dt: d\n   data: [ 1 ]\n",
            r"M1: opencv-matrix without rows",
        ),
        (
            "%YAML:1.0\nR: !!opencv-matrix\n   rows: 1\n   cols: 1\n   dt: d\n   data: [ 1 ]\n"
            "R: 2\n",
            r"R is given twice \(line 7\)",
        ),
        # Python's "cannot unpack non-iterable MappingNode object", a TypeError, for these.
        (
            "%YAML:1.0\nM1: !!opencv-matrix [ {rows: 3}, {cols: 3} ]\n",
            r"line 2: an opencv-matrix must be a mapping \(rows and cols, or sizes; dt, data\), "
            r"got a sequence",
        ),
        (
            "%YAML:1.0\nM1: !!opencv-nd-matrix 5\n",
            r"line 2: an opencv-nd-matrix must be a mapping \(rows and cols, or sizes; dt, "
            r"data\), got '5'",
        ),
        ("%YAML:1.0\nM1: [1, 2\n", r"not valid YAML: while parsing"),
        ("%YAML:1.0\n- 1\n- 2\n", r"a calibration file must be a YAML mapping, got list"),
        ("%YAML:1.0\n? [1, 2]\n: 3\n", r"keys must be names, got \[1, 2\]"),
        ("%YAML:1.0\nM1: !!python/object:os.system {}\n", r"not valid YAML: could not determine"),
        (
            "<?xml version='1.0'?>\n<opencv_storage>\n<M1 type_id='opencv-matrix'><rows>1</rows>"
            "<cols>2</cols><dt>d</dt><data>1 two</data></M1>\n</opencv_storage>\n",
            r"M1: opencv-matrix data must be numbers, got 'two'",
        ),
        (
            "<?xml version='1.0'?>\n<opencv_storage>\n<R>1</R><R>2</R></opencv_storage>\n",
            r"R is given twice",
        ),
        (
            "<?xml version='1.0'?>\n<storage></storage>\n",
            r"the XML root must be <opencv_storage>, got <storage>",
        ),
        ("<?xml version='1.0'?>\n<opencv_storage><M1>\n", r"not valid XML"),
        (
            "<?xml version='1.0'?>\n<!DOCTYPE x [<!ENTITY a 'aaaa'>]>\n<opencv_storage>"
            "</opencv_storage>\n",
            r"XML with a DOCTYPE or entities is not an OpenCV FileStorage",
        ),
    ],
)
def test_opencv_rejects_malformed(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ValueError, match=r"^\S*bad\.yml: " + message):
        read_stereo_calibration(write(tmp_path / "bad.yml", text))


def test_image_size_keyword(tmp_path: Path) -> None:
    path = write(tmp_path / "s.yml", opencv_yaml(stereo_entries()))
    assert read_stereo_calibration(
        path, image_size=(640, 480), translation_unit="mm"
    ).image_size == (640, 480)
    with pytest.raises(
        ValueError,
        match=r"s\.yml: the file gives an image size of \(640, 480\), "
        r"image_size= \(641, 480\)",
    ):
        read_stereo_calibration(path, image_size=(641, 480), translation_unit="mm")
    with pytest.raises(ValueError, match=r"image_size: image_size must be two whole numbers > 0"):
        read_stereo_calibration(path, image_size=(0, 480), translation_unit="mm")
    for wrong in ("640x480", (640,), (640, "480"), (True, 480)):
        with pytest.raises(TypeError, match=r"image_size must be \(width, height\) as two numbers"):
            read_stereo_calibration(path, image_size=wrong, translation_unit="mm")


def test_pyyaml_missing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write(tmp_path / "s.yml", opencv_yaml(stereo_entries()))
    monkeypatch.setitem(sys.modules, "yaml", None)
    with pytest.raises(ImportError, match=r'needs PyYAML: pip install "stereodepth\[calib\]"'):
        read_stereo_calibration(path)
    # XML, Middlebury and KITTI need no PyYAML
    xml = write(tmp_path / "s.xml", opencv_xml(stereo_entries()))
    assert read_stereo_calibration(xml, translation_unit="mm")


# --- ROS camera_info --------------------------------------------------------------------------
def ros_yaml(
    k: np.ndarray,
    d: np.ndarray,
    model: str,
    r: np.ndarray,
    p: np.ndarray,
    size: tuple[int, int] | None = (640, 480),
    name: str = "left",
) -> str:
    """A camera_info YAML laid out as ROS's camera_calibration writes it."""
    lines = []
    if size is not None:
        lines += [f"image_width: {size[0]}", f"image_height: {size[1]}"]
    lines.append(f"camera_name: narrow_stereo/{name}")
    for key, m in (
        ("camera_matrix", k),
        ("distortion_coefficients", d),
        ("rectification_matrix", r),
        ("projection_matrix", p),
    ):
        m2 = m if m.ndim == 2 else m.reshape(1, -1)
        lines += [
            f"{key}:",
            f"  rows: {m2.shape[0]}",
            f"  cols: {m2.shape[1]}",
            f"  data: [{fmt(m2)}]",
        ]
        if key == "camera_matrix":
            lines.append(f"distortion_model: {model}")
    return "\n".join(lines) + "\n"


def ros_pair(
    tmp_path: Path, left: dict[str, Any] | None = None, right: dict[str, Any] | None = None
) -> tuple[Path, Path]:
    """A rectified pair: both cameras turned onto a common frame, baseline 0.12 m."""
    r1, r2 = rot(0.002, -0.01, 0.003), rot(-0.001, 0.004, 0.002)
    kp = np.array([[690.0, 0.0, 300.0], [0.0, 690.0, 238.0], [0.0, 0.0, 1.0]])
    p1 = np.hstack([kp, np.zeros((3, 1))])
    p2 = np.hstack([kp, np.array([[-690.0 * 0.12], [0.0], [0.0]])])
    lk = {"k": K1, "d": D1, "model": "plumb_bob", "r": r1, "p": p1, "name": "left"}
    rk = {"k": K2, "d": D2, "model": "plumb_bob", "r": r2, "p": p2, "name": "right"}
    lk.update(left or {})
    rk.update(right or {})
    return (
        write(tmp_path / "left.yaml", ros_yaml(**lk)),
        write(tmp_path / "right.yaml", ros_yaml(**rk)),
    )


def test_a_size_of_0_x_0_is_not_known(tmp_path: Path) -> None:
    # camera_info_manager writes image_width: 0, image_height: 0 when it does not know the size
    # (and some drivers publish it so): that is no size, which image_size= (--image-size)
    # then gives, as for a file without the keys; 0 x 480 stays an error.
    lp, rp = ros_pair(tmp_path, {"size": (0, 0)}, {"size": (0, 0)})
    with pytest.raises(ValueError, match=r"no image size in the file .*pass image_size="):
        read_stereo_calibration(lp, second_path=rp)
    c = read_stereo_calibration(lp, second_path=rp, image_size=(640, 480))
    assert c.image_size == (640, 480)
    lp, rp = ros_pair(tmp_path, {"size": (0, 0)})  # the other file has it
    assert read_stereo_calibration(lp, second_path=rp).image_size == (640, 480)
    for fmt_, text in (
        ("yml", opencv_yaml(stereo_entries(image_width=0, image_height=0))),
        ("xml", opencv_xml(stereo_entries(image_width=0, image_height=0))),
        (
            "yml",
            opencv_yaml(stereo_entries(image_width=None, image_height=None, imageSize="[ 0, 0 ]")),
        ),
    ):
        path = write(tmp_path / f"zero.{fmt_}", text)
        with pytest.raises(ValueError, match=r"no image size in the file"):
            read_stereo_calibration(path, translation_unit="mm")
        c = read_stereo_calibration(path, translation_unit="mm", image_size=(640, 480))
        assert c.image_size == (640, 480)


def test_ros_pair(tmp_path: Path) -> None:
    lp, rp = ros_pair(tmp_path)
    c = read_stereo_calibration(lp, second_path=rp)
    r1, r2 = rot(0.002, -0.01, 0.003), rot(-0.001, 0.004, 0.002)
    np.testing.assert_allclose(c.R, r2.T @ r1, atol=1e-15)
    np.testing.assert_allclose(c.T, r2.T @ np.array([-0.12, 0.0, 0.0]), atol=1e-15)
    np.testing.assert_array_equal(c.K2, K2)
    np.testing.assert_array_equal(c.R1, r1)
    assert c.distortion_model == "plumb_bob" and c.image_size == (640, 480)
    assert c.Q is None and not c.rectified
    rig = c.to_rig()
    assert (rig.focal_px, rig.doffs_px) == (690.0, 0.0)
    assert rig.baseline_mm == pytest.approx(120.0, rel=1e-14)
    same = sc.read_ros_stereo_calibration(lp, rp, translation_unit="mm")
    np.testing.assert_allclose(same.T, c.T / 1000, rtol=1e-15)
    # the two ways of saying rational_polynomial and equidistant
    d8 = np.arange(1.0, 9.0) / 100
    lp, rp = ros_pair(
        tmp_path,
        {"d": d8, "model": "rational_polynomial"},
        {"d": d8, "model": "rational_polynomial"},
    )
    c = read_stereo_calibration(lp, second_path=rp)
    assert c.distortion_model == "plumb_bob" and c.D1.shape == (8,)
    lp, rp = ros_pair(
        tmp_path, {"d": D1[:4], "model": "equidistant"}, {"d": D2[:4], "model": "equidistant"}
    )
    assert read_stereo_calibration(lp, second_path=rp).distortion_model == "equidistant"


def test_ros_recovers_opencv_r_and_t(tmp_path: Path) -> None:
    """R and T recovered from stereoRectify's R1, R2, P1, P2 are the R and T it was given."""
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    for r, t in ((R, T_MM / 1000), (rot(-0.03, 0.01, 0.02), np.array([-0.5, 0.02, -0.01]))):
        r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(K1, D1, K2, D2, (640, 480), r, t.reshape(3, 1))
        lp, rp = ros_pair(tmp_path, {"r": r1, "p": p1}, {"r": r2, "p": p2})
        c = read_stereo_calibration(lp, second_path=rp)
        np.testing.assert_allclose(c.R, r, atol=1e-12)
        np.testing.assert_allclose(c.T, t, atol=1e-12)


def test_ros_rotations_printed_to_6_digits(tmp_path: Path) -> None:
    """camera_info files saved by ROS's C++ camera_calibration_parsers (and many copied by
    hand) print 6 significant digits: |R R^T - I| reaches about 3e-6 in each file and R =
    R2^T R1 composes two of them. Most such pairs were refused ("R must be a rotation ...
    1e-06", naming an R that is in neither file); they read as the nearest rotations."""
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    from stereodepth import StereoRectifier

    def six(a: np.ndarray) -> np.ndarray:
        return np.array([float(f"{v:.6g}") for v in a.ravel()]).reshape(a.shape)

    rng = np.random.default_rng(1)
    for t in (np.array([-0.12, 0.002, 0.001]), np.array([0.002, -0.12, 0.001])):
        for _ in range(8):
            r = rot(*rng.normal(scale=0.03, size=3))
            r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(
                K1, D1, K2, D2, (640, 480), r, t.reshape(3, 1)
            )
            lp, rp = ros_pair(tmp_path, {"r": six(r1), "p": six(p1)}, {"r": six(r2), "p": six(p2)})
            c = read_stereo_calibration(lp, second_path=rp)
            for m in (c.R1, c.R2):  # what the rectifier's 1e-6 check takes
                assert np.abs(m @ m.T - np.eye(3)).max() <= 1e-6
            np.testing.assert_allclose(c.R, r, atol=1e-5)
            np.testing.assert_allclose(c.T, t, atol=1e-6)
            np.testing.assert_allclose(c.R1, r1, atol=2e-6)
            StereoRectifier.from_calibration(c)  # the rectifier's own 1e-6 check passes


def camera_info_message(
    k: np.ndarray, d: np.ndarray, r: np.ndarray, p: np.ndarray, ros2: bool, **extra: str
) -> str:
    """A CameraInfo message as `rostopic echo -n1` (ROS 1: K, D, R, P as flow lists) or
    `ros2 topic echo --once` (ROS 2: k, d, r, p as block lists) prints it, "---" included."""

    def flat(name: str, a: np.ndarray) -> str:
        values = [repr(float(v)) for v in a.ravel()]
        if not ros2:
            return f"{name.upper()}: [{', '.join(values)}]"
        return f"{name}:\n" + "".join(f"- {v}\n" for v in values).rstrip("\n")

    stamp = "  stamp:\n    sec: 0\n    nanosec: 0" if ros2 else "  seq: 3\n  stamp:\n    secs: 0"
    lines = [
        f"header:\n{stamp}\n  frame_id: left",
        "height: 480",
        "width: 640",
        "distortion_model: plumb_bob" if ros2 else 'distortion_model: "plumb_bob"',
        flat("d", d),
        flat("k", k),
        flat("r", r),
        flat("p", p),
        f"binning_x: {extra.get('binning_x', '0')}",
        "binning_y: 0",
        "roi:",
        f"  x_offset: {extra.get('x_offset', '0')}",
        "  y_offset: 0",
        "  height: 0",
        "  width: 0",
        "  do_rectify: false",
        "---",
    ]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("ros2", [False, True])
def test_ros_camera_info_as_topic_echo_prints_it(tmp_path: Path, ros2: bool) -> None:
    """The camera_info a robot publishes, saved with `rostopic echo -n1` or `ros2 topic echo
    --once` (K, D, R, P or k, d, r, p as flat lists, width, height, a closing "---"): ROS 1's
    went to the OpenCV reader (its "R" is an OpenCV key) and failed with "missing key K1 or
    M1", ROS 2's was "not a calibration file this reader knows"."""
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    t = np.array([-0.12, 0.001, 0.0005])
    r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(K1, D1, K2, D2, (640, 480), R, t.reshape(3, 1))
    lp = write(tmp_path / "left.yaml", camera_info_message(K1, D1, r1, p1, ros2))
    rp = write(tmp_path / "right.yaml", camera_info_message(K2, D2, r2, p2, ros2))
    c = read_stereo_calibration(lp, second_path=rp)
    np.testing.assert_allclose(c.R, R, atol=1e-12)
    np.testing.assert_allclose(c.T, t, atol=1e-12)
    np.testing.assert_array_equal(c.K1, K1)
    np.testing.assert_array_equal(c.D2, D2)
    np.testing.assert_array_equal(c.P2, p2)
    assert c.image_size == (640, 480) and c.distortion_model == "plumb_bob"
    assert c.to_rig().baseline_mm == pytest.approx(1000 * np.linalg.norm(t), rel=1e-12)
    key = "p" if ros2 else "P"
    bad = camera_info_message(K2, D2, r2, p2[:, :3], ros2)
    with pytest.raises(ValueError, match=rf"right\.yaml: {key} must be 12 numbers .*got 9"):
        read_stereo_calibration(lp, second_path=write(tmp_path / "right.yaml", bad))
    bad = camera_info_message(K2, D2, r2, p2, ros2, binning_x="2")
    with pytest.raises(ValueError, match=r"right\.yaml: binning_x is 2: binned camera_info"):
        read_stereo_calibration(lp, second_path=write(tmp_path / "right.yaml", bad))
    bad = camera_info_message(K2, D2, r2, p2, ros2, x_offset="8")
    with pytest.raises(ValueError, match=r"right\.yaml: roi is .*a camera_info of a region"):
        read_stereo_calibration(lp, second_path=write(tmp_path / "right.yaml", bad))
    bad = camera_info_message(K2 * np.nan, D2, r2, p2, ros2)
    k_key = "k" if ros2 else "K"
    with pytest.raises(
        ValueError, match=rf"right\.yaml: {k_key} must be a list of numbers, got \['nan'"
    ):
        read_stereo_calibration(lp, second_path=write(tmp_path / "right.yaml", bad))


P_LEFT = np.hstack([np.array([[690.0, 0, 300], [0, 690, 238], [0, 0, 1]]), np.zeros((3, 1))])
P_FX700 = np.hstack([np.array([[700.0, 0, 300], [0, 690, 238], [0, 0, 1]]), [[-82.8], [0], [0]]])


@pytest.mark.parametrize(
    ("left", "right", "bad", "message"),
    [
        (
            {},
            {"model": "equidistant", "d": D2[:4]},
            "left\\.yaml \\+ .*right",
            r"distortion_model differs: 'plumb_bob' and 'equidistant'",
        ),
        ({}, {"size": (640, 481)}, "left\\.yaml \\+ .*right", r"image_width/image_height differ"),
        (
            {"size": None},
            {"size": None},
            "left\\.yaml \\+ .*right",
            r"no image size in the file \(image_width, image_height\): pass image_size=",
        ),
        (
            {},
            {"p": P_FX700},
            "left\\.yaml \\+ .*right",
            r"projection_matrix fx and fy differ between the cameras",
        ),
        ({}, {"p": P_LEFT}, "right", r"projection_matrix has no translation \(Tx = Ty = 0\)"),
        ({}, {"d": D2[:3]}, "right", r"distortion_coefficients has 3 coefficients; the plumb_bob"),
        (
            {"model": "rational_polynomial"},
            {"model": "rational_polynomial"},
            "left",
            r"distortion_coefficients has 5 coefficients; the rational_polynomial model takes 8",
        ),
        ({"model": "pinhole"}, {}, "left", r"distortion_model must be one of .*got 'pinhole'"),
        ({"r": np.eye(3) * 1.01}, {}, "left", "rectification_matrix " + NOT_ROTATION),
        ({"k": np.full((3, 3), np.inf)}, {}, "left", r"camera_matrix must be finite"),
        ({"p": P_LEFT[:, :3]}, {}, "left", r"projection_matrix must have shape \(3, 4\)"),
    ],
)
def test_ros_rejects(
    tmp_path: Path, left: dict[str, Any], right: dict[str, Any], bad: str, message: str
) -> None:
    lp, rp = ros_pair(tmp_path, left, right)
    with pytest.raises(ValueError, match=r"^\S*" + bad + r"\.yaml: " + message):
        read_stereo_calibration(lp, second_path=rp)


def test_ros_rejects_swapped_and_malformed(tmp_path: Path) -> None:
    lp, rp = ros_pair(tmp_path)
    with pytest.raises(
        ValueError,
        match=r"left\.yaml: projection_matrix has no translation .*"
        r"\(are the files swapped\?\)",
    ):
        read_stereo_calibration(rp, second_path=lp)
    with pytest.raises(
        ValueError,
        match=r"left\.yaml: a ROS camera_info file holds one camera: "
        "pass the right camera's file as second_path",
    ):
        read_stereo_calibration(lp)
    text = rp.read_text()
    cases = [
        (text.replace("rectification_matrix", "rect_matrix"), "missing key rectification_matrix"),
        (text.replace("distortion_model: plumb_bob\n", ""), "missing key distortion_model"),
        (
            text.replace("  rows: 3\n  cols: 4", "  rows: 3\n  cols: 3"),
            r"projection_matrix of 3x3 needs 9 values, got 12",
        ),
        (
            text.replace("camera_matrix:\n  rows: 3", "camera_matrix:\n  rows: three"),
            r"camera_matrix rows and cols must be whole numbers, got 'three', 3",
        ),
        (text.replace("data: [710.0", "data: [seven"), r"camera_matrix\.data must be numbers"),
        (
            text.replace("camera_matrix:\n", "camera_matrix: 7\nx:\n"),
            r"camera_matrix must be a mapping with rows, cols and data, got 7",
        ),
    ]
    for content, message in cases:
        rp.write_text(content)
        with pytest.raises(ValueError, match=r"^\S*right\.yaml: " + message):
            read_stereo_calibration(lp, second_path=rp)
    p_swapped = np.hstack([P_LEFT[:, :3], np.array([[690.0 * 0.12], [0.0], [0.0]])])
    lp, rp = ros_pair(tmp_path, {}, {"p": p_swapped})
    with pytest.raises(ValueError, match=r"right\.yaml: projection_matrix Tx = 82\.8 > 0") as e:
        read_stereo_calibration(lp, second_path=rp)
    # both causes: files swapped, or a Tx of the wrong sign (ROS's convention named)
    assert "Tx = -fx * baseline < 0" in str(e.value) and "Tx's sign wrong" in str(e.value)


# --- Kalibr -----------------------------------------------------------------------------------
def kalibr_yaml(cams: list[dict[str, Any]]) -> str:
    out = []
    for n, c in enumerate(cams):
        out.append(f"cam{n}:")
        if "T" in c:
            out.append("  T_cn_cnm1:")
            out += [f"  - [{fmt(row)}]" for row in c["T"]]
        out += [
            f"  cam_overlaps: [{n - 1 if n else 1}]",
            f"  camera_model: {c.get('camera_model', 'pinhole')}",
            f"  distortion_coeffs: [{fmt(c.get('d', D1[:4]))}]",
            f"  distortion_model: {c.get('model', 'radtan')}",
            f"  intrinsics: [{fmt(c.get('intrinsics', [458.6, 457.3, 367.2, 248.4]))}]",
            f"  resolution: {c.get('resolution', [752, 480])}",
            f"  rostopic: /cam{n}/image_raw",
        ]
    return "\n".join(out) + "\n"


def transform(r: np.ndarray, t: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


RA, TA = rot(0.001, 0.002, -0.003), np.array([-0.11, 0.0004, 0.0002])
RB, TB = rot(-0.002, 0.01, 0.001), np.array([-0.09, 0.001, -0.0003])


def test_kalibr(tmp_path: Path) -> None:
    path = write(
        tmp_path / "camchain.yaml",
        kalibr_yaml([{}, {"T": transform(RA, TA), "d": D2[:4]}, {"T": transform(RB, TB)}]),
    )
    c = read_stereo_calibration(path)
    np.testing.assert_array_equal(c.R, RA)
    np.testing.assert_array_equal(c.T, TA)
    np.testing.assert_array_equal(c.K1, [[458.6, 0, 367.2], [0, 457.3, 248.4], [0, 0, 1]])
    np.testing.assert_array_equal(c.D2, D2[:4])
    assert c.distortion_model == "plumb_bob" and c.image_size == (752, 480)
    with pytest.raises(ValueError, match=r"camchain\.yaml: this calibration is not rectified"):
        c.to_rig()
    # along the chain and backwards
    c02 = sc.read_kalibr_stereo_calibration(path, cameras=(0, 2))
    np.testing.assert_allclose(c02.R, RB @ RA, atol=1e-15)
    np.testing.assert_allclose(c02.T, RB @ TA + TB, atol=1e-15)
    c10 = read_stereo_calibration(path, cameras=(1, 0))
    np.testing.assert_allclose(c10.R, RA.T, atol=1e-15)
    np.testing.assert_allclose(c10.T, -RA.T @ TA, atol=1e-15)
    fish = write(
        tmp_path / "fish.yaml",
        kalibr_yaml([{"model": "equidistant"}, {"T": transform(RA, TA), "model": "equidistant"}]),
    )
    assert read_stereo_calibration(fish).distortion_model == "equidistant"


def test_ros_and_kalibr_refuse_a_baseline_in_mm_read_as_metres(tmp_path: Path) -> None:
    """A ROS or Kalibr calibration of a target measured in mm (``--square 108`` for 0.108 m)
    says metres by convention but holds a 120 m baseline: it was read so without a word, every
    depth 1000 times too large. As for OpenCV files, over 10 m needs translation_unit."""
    kp = np.array([[690.0, 0.0, 300.0], [0.0, 690.0, 238.0], [0.0, 0.0, 1.0]])
    p1 = np.hstack([kp, np.zeros((3, 1))])
    p2 = np.hstack([kp, np.array([[-690.0 * 120.0], [0.0], [0.0]])])
    lp, rp = ros_pair(tmp_path, {"p": p1}, {"p": p2})
    with pytest.raises(
        ValueError,
        match=r"right\.yaml: projection_matrix gives a baseline of 120: read as metres "
        r"\(ROS's convention; no translation unit given\) that is an unlikely 120 m.*'mm'",
    ):
        read_stereo_calibration(lp, second_path=rp)
    c = read_stereo_calibration(lp, second_path=rp, translation_unit="mm")
    assert c.baseline_m == pytest.approx(0.12, rel=1e-14)
    c = read_stereo_calibration(lp, second_path=rp, translation_unit="m")
    assert c.baseline_m == pytest.approx(120.0, rel=1e-14)
    path = write(
        tmp_path / "camchain.yaml",
        kalibr_yaml([{}, {"T": transform(RA, TA * 1000)}, {"T": transform(RB, TB * 1000)}]),
    )
    with pytest.raises(
        ValueError,
        match=r"camchain\.yaml: cam2\.T_cn_cnm1 @ cam1\.T_cn_cnm1 gives a baseline of 200\.?\d*: "
        r"read as metres \(Kalibr's convention",
    ):
        read_stereo_calibration(path, cameras=(2, 0))
    with pytest.raises(ValueError, match=r"cam1\.T_cn_cnm1 gives a baseline of 110"):
        read_stereo_calibration(path)
    c = read_stereo_calibration(path, translation_unit="mm")
    np.testing.assert_allclose(c.T, TA, rtol=1e-15)
    # a long rig in metres is accepted when said so (and a 9 m one without a word)
    np.testing.assert_array_equal(read_stereo_calibration(path, translation_unit="m").T, TA * 1000)
    nine = write(tmp_path / "nine.yaml", kalibr_yaml([{}, {"T": transform(RA, [-9.0, 0, 0])}]))
    assert read_stereo_calibration(nine).baseline_m == 9.0


@pytest.mark.parametrize(
    ("cams", "message"),
    [
        ([{}], r"missing key cam1"),
        ([{}, {}], r"missing key cam1\.T_cn_cnm1"),
        (
            [{"camera_model": "omni"}, {"T": transform(RA, TA)}],
            r"cam0\.camera_model must be 'pinhole', got 'omni'",
        ),
        ([{}, {"T": transform(RA * 1.01, TA)}], r"cam1\.T_cn_cnm1\[:3, :3\] " + NOT_ROTATION),
        (
            [{}, {"T": transform(RA, TA) + np.diag([0, 0, 0, 1.0])}],
            r"cam1\.T_cn_cnm1 must end with the row 0 0 0 1, got \[0\.0, 0\.0, 0\.0, 2\.0\]",
        ),
        ([{}, {"T": transform(RA, TA)[:3]}], r"cam1\.T_cn_cnm1 must have shape \(4, 4\)"),
        (
            [{}, {"T": transform(RA, TA), "d": D1}],
            r"cam1\.distortion_coeffs has 5 coefficients; the radtan model takes 4",
        ),
        (
            [{"model": "equidistant", "d": D1}, {"T": transform(RA, TA)}],
            r"cam0\.distortion_coeffs has 5 coefficients; the equidistant model takes 4",
        ),
        (
            [{"model": "fov", "d": [0.9]}, {"T": transform(RA, TA)}],
            r"cam0\.distortion_model must be one of",
        ),
        (
            [{}, {"T": transform(RA, TA), "model": "equidistant"}],
            r"cam0 and cam1 have different distortion models: 'plumb_bob' and 'equidistant'",
        ),
        (
            [{}, {"T": transform(RA, TA), "resolution": [640, 480]}],
            r"cam0 and cam1 resolutions differ: \(752, 480\) and \(640, 480\)",
        ),
        (
            [{"intrinsics": [458.6, 457.3, 367.2]}, {"T": transform(RA, TA)}],
            r"cam0\.intrinsics must have shape \(4,\), got \(3,\)",
        ),
        (
            [{"intrinsics": [458.6, -457.3, 367.2, 1]}, {"T": transform(RA, TA)}],
            r"cam0\.intrinsics focal lengths must be > 0",
        ),
        (
            [{"resolution": [752]}, {"T": transform(RA, TA)}],
            r"cam0\.resolution must be \(width, height\), got \[752\]",
        ),
    ],
)
def test_kalibr_rejects(tmp_path: Path, cams: list[dict[str, Any]], message: str) -> None:
    path = write(tmp_path / "camchain.yaml", kalibr_yaml(cams))
    with pytest.raises(ValueError, match=r"^\S*camchain\.yaml: " + message):
        sc.read_kalibr_stereo_calibration(path)


def test_kalibr_rejects_cameras(tmp_path: Path) -> None:
    path = write(tmp_path / "camchain.yaml", kalibr_yaml([{}, {"T": transform(RA, TA)}]))
    for cameras, message in (
        ((0, 0), "two different cameras"),
        ((0,), "two camera numbers"),
        ((0, -1), "two whole numbers >= 0"),
        ((0, 2), "missing key cam2"),
    ):
        with pytest.raises(ValueError, match=message):
            read_stereo_calibration(path, cameras=cameras)  # type: ignore[arg-type]
    # A wrong type is a TypeError (bool was refused as a ValueError); numpy integers, as
    # every other integer parameter of the package takes them, were refused.
    for cameras in ((0, True), (0, "1"), (0.0, 1)):
        with pytest.raises(TypeError, match=r"cameras must be two whole numbers >= 0, got"):
            read_stereo_calibration(path, cameras=cameras)  # type: ignore[arg-type]
    np_cams = (np.int64(1), np.uint8(0))
    c10 = read_stereo_calibration(path, cameras=np_cams)  # type: ignore[arg-type]
    ref = read_stereo_calibration(path, cameras=(1, 0))
    for key in ("K1", "D1", "K2", "D2", "R", "T"):
        np.testing.assert_array_equal(getattr(c10, key), getattr(ref, key), strict=True)


# --- Middlebury and KITTI: already rectified ----------------------------------------------------
MIDDLEBURY = (
    "cam0=[3950.25 0 1180.5; 0 3950.25 1005.75; 0 0 1]\n"
    "cam1=[3950.25 0 1310.125; 0 3950.25 1005.75; 0 0 1]\n"
    "doffs=129.625\nbaseline=190.5\nwidth=2900\nheight=1950\nndisp=280\n"
)


def test_middlebury(tmp_path: Path) -> None:
    path = write(tmp_path / "calib.txt", MIDDLEBURY.replace("\n", "\r\n"))
    c = read_stereo_calibration(path)
    assert c.rectified and c.distortion_model == "none" and c.D1.shape == (0,)
    np.testing.assert_array_equal(c.R, np.eye(3))
    np.testing.assert_array_equal(c.T, [-0.1905, 0.0, 0.0])
    assert c.image_size == (2900, 1950) and c.K2[0, 2] == 1310.125
    rig = c.to_rig()
    want = StereoRig.from_middlebury_calib(path)
    assert (rig.baseline_mm, rig.focal_px) == (want.baseline_mm, want.focal_px) == (190.5, 3950.25)
    assert rig.doffs_px == pytest.approx(want.doffs_px, rel=1e-14)  # cx1 - cx0 in floating point
    assert (rig.width_px, rig.height_px) == (want.width_px, want.height_px)
    # Q keeps doffs: Z = f B / (d + doffs), as the rig says
    d = 50.0
    _, _, z, w = c.Q @ np.array([1000.0, 900.0, d, 1.0])
    assert z / w == pytest.approx(rig.depth_m(d), rel=1e-12)
    # a file without width and height needs image_size=
    small = write(tmp_path / "small.txt", "cam0=[700 0 300; 0 700 200; 0 0 1]\nbaseline=160\n")
    with pytest.raises(ValueError, match=r"small\.txt: no image size in the file \(width, height"):
        read_stereo_calibration(small)
    c = sc.read_middlebury_stereo_calibration(small, image_size=(600, 400))
    assert c.image_size == (600, 400) and c.to_rig().doffs_px == 0.0
    with pytest.raises(
        ValueError,
        match=r"small\.txt: translation_unit does not apply to a "
        "Middlebury file",
    ):
        read_stereo_calibration(small, translation_unit="mm", image_size=(600, 400))
    with pytest.raises(ValueError, match=r"calib\.txt: baseline must be > 0 mm"):
        read_stereo_calibration(write(tmp_path / "calib.txt", MIDDLEBURY.replace("190.5", "0")))


P2_2012 = (
    "7.100000e+02 0.000000e+00 6.000000e+02 4.400000e+01 0.000000e+00 7.100000e+02 "
    "1.750000e+02 2.000000e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.500000e-03"
)
P3_2012 = (
    "7.100000e+02 0.000000e+00 6.000000e+02 -3.400000e+02 0.000000e+00 7.100000e+02 "
    "1.750000e+02 2.200000e+00 0.000000e+00 0.000000e+00 1.000000e+00 2.700000e-03"
)
P0_2012 = (
    "7.100000e+02 0.000000e+00 6.000000e+02 0.000000e+00 0.000000e+00 7.100000e+02 "
    "1.750000e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00"
)


def kitti_2012() -> str:
    p1 = P0_2012.replace("0.000000e+00 0.000000e+00 7", "-3.800000e+02 0.000000e+00 7", 1)
    return (
        f"P0: {P0_2012}\nP1: {p1}\nP2: {P2_2012}\nP3: {P3_2012}\n"
        "R0_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: 1 0 0 0 0 1 0 0 0 0 1 0\n"
    )


def test_kitti(tmp_path: Path) -> None:
    path = write(tmp_path / "000070.txt", kitti_2012())
    with pytest.raises(
        ValueError,
        match=r"000070\.txt: no image size in the file \(S_rect_02\): "
        r"pass image_size=\(width, height\)",
    ):
        read_stereo_calibration(path)
    c = read_stereo_calibration(path, image_size=(1242, 375))
    assert c.rectified and c.distortion_model == "none" and c.image_size == (1242, 375)
    baseline = (4.4e01 + 3.4e02) / 7.1e02
    np.testing.assert_array_equal(c.T, [-baseline, 0.0, 0.0])
    np.testing.assert_array_equal(c.K1, np.array(P2_2012.split(), float).reshape(3, 4)[:, :3])
    rig = c.to_rig()
    assert (rig.focal_px, rig.doffs_px) == (710.0, 0.0)
    assert rig.baseline_mm == pytest.approx(baseline * 1000, rel=1e-15)
    c01 = read_stereo_calibration(path, image_size=(1242, 375), cameras=(0, 1))
    assert c01.to_rig().baseline_mm == pytest.approx(380.0 / 710.0 * 1000, rel=1e-15)
    # calib_cam_to_cam.txt of KITTI 2015: P_rect_0N and the image size S_rect_0N, CR LF
    text = (
        "calib_time: 09-Jan-2012 13:57:47\ncorner_dist: 9.950000e-02\n"
        "S_rect_02: 1.242000e+03 3.750000e+02\n"
        f"P_rect_02: {P2_2012}\nS_rect_03: 1.242000e+03 3.750000e+02\nP_rect_03: {P3_2012}\n"
    )
    c = read_stereo_calibration(write(tmp_path / "cam_to_cam.txt", text.replace("\n", "\r\n")))
    assert c.image_size == (1242, 375)
    np.testing.assert_array_equal(c.T, [-baseline, 0.0, 0.0])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (kitti_2012().replace("P3:", "Q3:"), r": missing P3 \(or P_rect_03\)"),
        (kitti_2012() + f"P_rect_02: {P2_2012}\n", r":7: P_rect_02 gives camera 2 again"),
        (kitti_2012() + f"P2: {P2_2012}\n", r":7: P2 is given twice \(first on line 3\)"),
        (kitti_2012().replace(" 2.500000e-03", ""), r":3: P2 must be 12 numbers, got 11"),
        (kitti_2012().replace("2.500000e-03", "x"), r":3: P2 must be 12 numbers, got '7"),
        (kitti_2012().replace("2.500000e-03", "nan"), r":3: P2 must be 12 finite numbers"),
        (kitti_2012().replace("2.500000e-03", "1e999"), r":3: P2 must be 12 finite numbers"),
        (kitti_2012() + "just words\n", r":7: expected 'NAME: values', got 'just words'"),
        (
            kitti_2012().replace(P3_2012, P3_2012.replace("-3.400000e+02", "3.400000e+02")),
            r": camera 3 must be right of camera 2, got a baseline of -0\.4",
        ),
        (
            kitti_2012().replace(P3_2012, P3_2012.replace("1.750000e+02", "1.7e+02")),
            r": P2 and P3 are not a rectified pair: their principal point row cy differ \(175\.0 ",
        ),
        (
            kitti_2012().replace(
                P2_2012, P2_2012.replace("0.000000e+00 0.000000e+00 1.0", "0 1 1.0")
            ),
            r": P2 must be a rectified projection \[fx 0 cx tx; 0 fy cy ty; 0 0 1 tz\]",
        ),
        (kitti_2012() + "S_rect_02: 1242 0\n", r": S_rect_02 must be two whole numbers > 0"),
    ],
)
def test_kitti_rejects(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ValueError, match=r"^\S*calib\.txt" + message):
        sc.read_kitti_stereo_calibration(
            write(tmp_path / "calib.txt", text), image_size=(1242, 375)
        )


# --- the type itself, and the format detection -------------------------------------------------
def fields(**changes: Any) -> dict[str, Any]:
    f: dict[str, Any] = {
        "K1": K1,
        "D1": D1,
        "K2": K2,
        "D2": D2,
        "distortion_model": "plumb_bob",
        "R": R,
        "T": T_MM / 1000,
        "image_size": (640, 480),
    }
    f.update(changes)
    return f


def test_direct_construction() -> None:
    c = StereoCalibration(**fields(D1=D1.tolist(), T=(T_MM / 1000).reshape(3, 1)))
    assert c.D1.dtype == np.float64 and c.D1.shape == (5,) and c.T.shape == (3,)
    assert c.baseline_m == pytest.approx(np.linalg.norm(T_MM) / 1000)
    assert c.distortion_model == "plumb_bob"
    with pytest.raises(AttributeError):
        c.R = np.eye(3)  # type: ignore[misc]
    assert StereoCalibration(**fields(distortion_model="RadTan")).distortion_model == "plumb_bob"


@pytest.mark.parametrize(
    ("changes", "exc", "message"),
    [
        ({"R": np.diag([1.0, 1.0, -1.0])}, ValueError, r"StereoCalibration: R " + NOT_ROTATION),
        ({"K2": np.eye(2)}, ValueError, r"StereoCalibration: K2 must have shape \(3, 3\)"),
        (
            {"D2": D2[:4], "distortion_model": "equidistant", "D1": D1},
            ValueError,
            r"D1 has 5 coefficients; the equidistant model takes 4",
        ),
        ({"distortion_model": "none"}, ValueError, r"D1 has 5 coefficients; the none model"),
        ({"distortion_model": 3}, ValueError, r"distortion_model must be one of"),
        ({"image_size": (640,)}, ValueError, r"image_size must be \(width, height\)"),
        ({"image_size": (True, 480)}, ValueError, r"image_size must be two whole numbers > 0"),
        ({"T": [0.0, 0.0, np.nan]}, ValueError, r"T must be finite"),
        ({"P2": np.zeros((3, 3))}, ValueError, r"P2 must have shape \(3, 4\)"),
        ({"P1": np.zeros((3, 4))}, ValueError, r"P1\[:, :3\] focal lengths must be > 0"),
        ({"image_size": "64"}, ValueError, r"image_size must be \(width, height\), got '64'"),
        (
            {"rectified": True},
            ValueError,
            r"a rectified calibration has R = identity and distortion_model 'none'",
        ),
        ({"rectified": 1}, TypeError, r"rectified must be a bool, got 1"),
        ({"source": Path("x")}, TypeError, r"source must be a str"),
        ({"source": "mine.yml", "K1": K1 * 0}, ValueError, r"mine\.yml: K1 focal lengths"),
    ],
)
def test_direct_construction_rejects(changes: dict[str, Any], exc: type, message: str) -> None:
    with pytest.raises(exc, match=message):
        StereoCalibration(**fields(**changes))


def test_to_rig_rejects() -> None:
    rect = {"D1": [], "D2": [], "distortion_model": "none", "R": np.eye(3), "rectified": True}
    with pytest.raises(ValueError, match=r"rectified pair has the same fx, fy and cy in K1 and K2"):
        StereoCalibration(**fields(**rect, T=[-0.1, 0, 0])).to_rig()
    k = {"K2": K1}
    with pytest.raises(ValueError, match=r"a rectified horizontal pair has T = \(-B, 0, 0\)"):
        StereoCalibration(**fields(**rect, **k, T=[-0.1, 0.01, 0])).to_rig()
    with pytest.raises(ValueError, match=r"the right camera must be to the right of the left") as e:
        StereoCalibration(**fields(**rect, **k, T=[0.1, 0, 0])).to_rig()
    # the convention and the remedies, as StereoRectifier.rig's refusal
    assert "T[0] = 0.1 m" in str(e.value) and "T[0] < 0" in str(e.value)
    assert "replace R by R.T, T by -R.T @ T" in str(e.value)
    p_right = P_LEFT + np.array([[0, 0, 0, 50.0], [0, 0, 0, 0], [0, 0, 0, 0]])
    with pytest.raises(ValueError, match=r"P2\[0, 3\] - P1\[0, 3\] = 50\.0; OpenCV's"):
        StereoCalibration(**fields(P1=P_LEFT, P2=p_right)).to_rig()
    p1 = P_LEFT
    p2 = P_LEFT + np.array([[0, 0, 0, 0], [0, 0, 0, -50.0], [0, 0, 0, 0]])
    with pytest.raises(ValueError, match=r"P2 is of a vertical pair"):
        StereoCalibration(**fields(P1=p1, P2=p2)).to_rig()


def test_direct_construction_from_stereo_calibrate_rational_output() -> None:
    # cv2.stereoCalibrate with CALIB_RATIONAL_MODEL returns D1, D2 of shape (1, 14), zeros
    # after the 8th (OpenCV 5.0); the OpenCV file reader took such a file, but a
    # StereoCalibration built from the same results refused them ("D1 has 14 coefficients;
    # the plumb_bob model takes 4 or 5 or 8").
    d8 = np.array([0.1, -0.2, 0.001, 0.002, 0.03, 0.01, -0.02, 0.004])
    for count in (12, 14):
        d = np.zeros((1, count))
        d[0, :8] = d8
        c = StereoCalibration(**fields(D1=d, D2=d))
        np.testing.assert_array_equal(c.D1, d8)
        np.testing.assert_array_equal(c.D2, d8)
        d[0, 9] = 1e-3
        with pytest.raises(
            ValueError, match=f"D1 has thin prism or tilt terms .coefficients 9 to {count}"
        ):
            StereoCalibration(**fields(D1=d, D2=d))


def test_to_rig_takes_what_the_rectified_readers_take(tmp_path: Path) -> None:
    # read_middlebury_calib and read_kitti_calib take a cam1 / P3 whose fx, fy or cy differ
    # from the left camera's within 1e-6 relative (the last printed digit); read_calibration
    # and StereoRectifier gave such a file a rig, and to_rig refused it ("a rectified pair
    # has the same fx, fy and cy in K1 and K2", without the values).
    mb = write(tmp_path / "calib.txt",
               "cam0=[1758.23 0 953.34; 0 1758.23 552.29; 0 0 1]\n"
               "cam1=[1758.23 0 953.34; 0 1758.23 552.2901; 0 0 1]\n"
               "doffs=0\nbaseline=111.53\nwidth=1920\nheight=1080\nndisp=290\n")  # fmt: skip
    rig = read_stereo_calibration(mb).to_rig()
    flat = sc.read_calibration(mb)
    assert (rig.focal_px, rig.baseline_mm, rig.doffs_px) == (1758.23, 111.53, 0.0)
    assert (flat.focal_px, flat.baseline_m * 1000, flat.doffs_px) == (1758.23, 111.53, 0.0)
    p2 = "718.856 0 607.1928 45.38225 0 718.856 185.2157 -0.1130887 0 0 1 0.003779761"
    p3 = "718.8561 0 607.1928 -337.2877 0 718.8561 185.2157 2.369057 0 0 1 0.004915215"
    kitti = write(tmp_path / "calib_kitti.txt", f"P2: {p2}\nP3: {p3}\n")
    rig = read_stereo_calibration(kitti, image_size=(1241, 376)).to_rig()
    assert rig.baseline_mm == pytest.approx(sc.read_calibration(kitti).baseline_m * 1000)
    off = write(tmp_path / "off.txt", f"P2: {p2}\nP3: {p3.replace('718.8561', '718.9')}\n")
    with pytest.raises(ValueError, match="their focal length fx differ"):
        read_stereo_calibration(off, image_size=(1241, 376))
    direct = StereoCalibration(**fields(D1=[], D2=[], distortion_model="none", R=np.eye(3),
                                        rectified=True, T=[-0.1, 0, 0]))  # fmt: skip
    with pytest.raises(ValueError, match=r"same fx, fy and cy in K1 and K2, got fx 700\.0 and 710"):
        direct.to_rig()


def test_to_rig_of_kitti_projections_in_a_ros_pair(tmp_path: Path) -> None:
    # KITTI's P_rect_02 and P_rect_03 (raw calib_cam_to_cam.txt of 2011_09_26) in a ROS
    # camera_info pair, as converters to rosbag write them: both cameras in camera 0's
    # frame, so P[1, 3] differs by the sub-millimetre y offsets. to_rig refused it as "a
    # vertical pair" while StereoRectifier.rig took it as the horizontal pair it is.
    from stereodepth.rectify import StereoRectifier

    p2 = np.array([[721.5377, 0, 609.5593, 44.85728], [0, 721.5377, 172.854, 0.2163791],
                   [0, 0, 1, 0.002745884]])  # fmt: skip
    p3 = np.array([[721.5377, 0, 609.5593, -339.5242], [0, 721.5377, 172.854, 2.199936],
                   [0, 0, 1, 0.002729905]])  # fmt: skip
    none = np.zeros(5)
    left = write(tmp_path / "l.yaml", ros_yaml(p2[:, :3], none, "plumb_bob", np.eye(3), p2,
                                               (1242, 375)))  # fmt: skip
    right = write(tmp_path / "r.yaml", ros_yaml(p3[:, :3], none, "plumb_bob", np.eye(3), p3,
                                                (1242, 375), "right"))  # fmt: skip
    calib = read_stereo_calibration(left, second_path=right)
    rig = calib.to_rig()
    baseline_mm = (44.85728 + 339.5242) / 721.5377 * 1000  # the devkit's B
    assert rig.baseline_mm == pytest.approx(baseline_mm, rel=1e-12)
    assert (rig.focal_px, rig.doffs_px, rig.width_px, rig.height_px) == (721.5377, 0, 1242, 375)
    rect = StereoRectifier.from_calibration(calib)
    assert not rect.vertical
    assert rect.rig.baseline_mm == pytest.approx(rig.baseline_mm, rel=1e-12)


def test_unknown_formats_and_keywords(tmp_path: Path) -> None:
    for text in ("name: nothing\n", "a = b\n", "<?xml version='1.0'?>\n<opencv_storage/>\n"):
        path = write(tmp_path / "x.cfg", text)
        with pytest.raises(
            ValueError,
            match=r"x\.cfg: (not a calibration file this reader knows|"
            "missing key K1 or M1 or cameraMatrix1)",
        ):
            read_stereo_calibration(path)
    with pytest.raises(FileNotFoundError, match=r"calibration file not found: .*nope\.yml"):
        read_stereo_calibration(tmp_path / "nope.yml")
    (tmp_path / "dir.yml").mkdir()
    with pytest.raises(IsADirectoryError, match=r"calibration file is a folder, not a file"):
        read_stereo_calibration(tmp_path / "dir.yml")
    opencv = write(tmp_path / "s.yml", opencv_yaml(stereo_entries()))
    with pytest.raises(ValueError, match=r"s\.yml: cameras does not apply to a OpenCV file"):
        read_stereo_calibration(opencv, cameras=(0, 1))
    kitti = write(tmp_path / "k.txt", kitti_2012())
    with pytest.raises(ValueError, match=r"k\.txt: distortion_model does not apply to a KITTI"):
        read_stereo_calibration(kitti, distortion_model="none", image_size=(1242, 375))
    # OpenCV YAML without the directive or the tags (as PyYAML-based scripts write it)
    plain = "\n".join(
        [
            f"K1: [{fmt(K1)}]",
            f"D1: [{fmt(D1)}]",
            f"K2: [{fmt(K2)}]",
            f"D2: [{fmt(D2)}]",
            f"R: {np.array2string(R, separator=', ')}".replace("\n", ""),
            f"T: [{fmt(T_MM)}]",
            "image_size: [640, 480]",
        ]
    )
    with pytest.raises(ValueError, match=r"plain\.yml: K1 must have shape \(3, 3\), got \(9,\)"):
        read_stereo_calibration(write(tmp_path / "plain.yml", plain))
    nested = plain.replace(f"K1: [{fmt(K1)}]", f"K1: {K1.tolist()}").replace(
        f"K2: [{fmt(K2)}]", f"K2: {K2.tolist()}"
    )
    c = read_stereo_calibration(write(tmp_path / "plain.yml", nested), translation_unit="mm")
    np.testing.assert_allclose(c.R, R, atol=1e-8)
    np.testing.assert_array_equal(c.T, T_MM / 1000)


def test_rectified_format_tells_rectified_files_from_raw_ones(tmp_path: Path) -> None:
    kitti = write(tmp_path / "k.txt", kitti_2012())
    mb = write(tmp_path / "calib.txt", "cam0=[700 0 300; 0 700 200; 0 0 1]\r\nbaseline=100\r\n")
    raw = write(tmp_path / "s.yaml", "%YAML:1.0\n---\nR: !!opencv-matrix\n")
    assert sc.rectified_format(kitti) == "kitti"
    assert sc.rectified_format(mb) == "middlebury"
    assert sc.rectified_format(raw) is None
    with pytest.raises(FileNotFoundError, match="calibration file not found"):
        sc.rectified_format(tmp_path / "missing.txt")


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("deep.yml", "M1: " + "[" * 5000 + "]" * 5000 + "\n"),
        ("deep.xml", '<?xml version="1.0"?>\n<opencv_storage>' + "<a>" * 5000 + "</a>" * 5000
         + "</opencv_storage>\n"),
    ],
)  # fmt: skip
def test_deeply_nested_file_is_a_value_error(tmp_path: Path, name: str, text: str) -> None:
    """A file nested past Python's recursion limit is refused like any other malformed file
    (it used to escape as RecursionError, a traceback on the command line)."""
    p = write(tmp_path / name, text)
    with pytest.raises(ValueError, match="nested too deeply to be a calibration file") as info:
        read_stereo_calibration(p)
    assert str(p) in str(info.value)


def test_error_message_of_a_huge_value_stays_short(tmp_path: Path) -> None:
    """A huge value (a YAML alias bomb: 9**5 strings in a file of 300 bytes; 5000 distortion
    coefficients) is named in a message of a few lines, not megabytes."""
    levels = ["a: &a [x, x, x, x, x, x, x, x, x]"]
    for prev, cur in zip("abcd", "bcde", strict=True):
        levels.append(f"{cur}: &{cur} [" + ", ".join([f"*{prev}"] * 9) + "]")
    p = write(tmp_path / "bomb.yml", "\n".join(levels) + "\nM1: *e\n")
    with pytest.raises(ValueError, match=r"M1 must be numbers, got \[\[") as info:
        read_stereo_calibration(p)
    assert len(str(info.value)) < 2000
    long = np.arange(5000.0)
    long[-1] = np.nan
    p = write(tmp_path / "long.yml", opencv_yaml(stereo_entries(D1=long)))
    with pytest.raises(ValueError, match=r"D1 must be finite, got \[0\.0, 1\.0, .*\.\.\.") as info:
        read_stereo_calibration(p)
    assert len(str(info.value)) < 2000


def test_opencv_second_file_without_opencv_keys_is_refused(tmp_path: Path) -> None:
    """``--calib stereo.yml --calib-right right.yaml`` (a ROS file given to an OpenCV one) used
    to be merged and silently ignored; a second file must hold part of the calibration."""
    full = write(tmp_path / "stereo.yml", opencv_yaml(stereo_entries()))
    ros = write(
        tmp_path / "right.yaml",
        "image_width: 640\nimage_height: 480\ncamera_name: right\ncamera_matrix: {rows: 3}\n",
    )
    with pytest.raises(ValueError, match=r"right\.yaml: none of the matrices of an OpenCV"):
        read_stereo_calibration(full, second_path=ros)
    with pytest.raises(
        ValueError,
        match=r"its keys: \['camera_matrix', 'camera_name', 'image_height', 'image_width'\]",
    ):
        sc.read_opencv_stereo_calibration(full, ros)


def test_a_file_too_large_for_a_calibration_is_refused_at_once(tmp_path: Path) -> None:
    """A large text file given by mistake (an ASCII point cloud) is refused by its size; the
    YAML parser took about 3 s per MB over it before saying it was no calibration."""
    from stereodepth.calib._common import MAX_FILE_BYTES

    p = tmp_path / "cloud.txt"
    p.write_text("0.25 0.5 0.75\n" * (MAX_FILE_BYTES // 14 + 1))
    with pytest.raises(ValueError, match=r"cloud\.txt: \d+ bytes is too large for a calibration"):
        read_stereo_calibration(p)
    with pytest.raises(ValueError, match="too large"):
        sc.read_kalibr_stereo_calibration(p)
    p.write_text("0.25 0.5 0.75\n")  # a small file still gets the reader's own answer
    with pytest.raises(ValueError, match="not a calibration file this reader knows"):
        read_stereo_calibration(p)


def test_integers_beyond_a_double_are_refused_naming_the_file(tmp_path: Path) -> None:
    """YAML and JSON integers have no size limit: one beyond a double's range raised
    OverflowError (a traceback from `stereodepth match --calib`) instead of the reader's
    ValueError naming the file and the key."""
    huge = "1" + "0" * 400
    text = opencv_yaml(stereo_entries(image_width=huge))
    with pytest.raises(ValueError, match=r"big_w\.yml: image_width, image_height must be two"):
        read_stereo_calibration(write(tmp_path / "big_w.yml", text), translation_unit="mm")
    text = opencv_yaml(stereo_entries()).replace(fmt(T_MM.reshape(3, 1)), f"-{huge}, 0.0, 0.0")
    assert huge in text
    with pytest.raises(ValueError, match=r"big_t\.yml: T must be finite, got \[-inf, 0\.0, 0\.0\]"):
        read_stereo_calibration(write(tmp_path / "big_t.yml", text), translation_unit="mm")
    cams = [{"resolution": [752, 480]}, {"T": np.eye(4), "resolution": [752, 480]}]
    text = kalibr_yaml(cams).replace("intrinsics: [458.6", f"intrinsics: [{huge}", 1)
    with pytest.raises(ValueError, match=r"camchain\.yaml: .*intrinsics"):
        read_stereo_calibration(write(tmp_path / "camchain.yaml", text))


def test_an_empty_distortion_list_is_no_distortion(tmp_path: Path) -> None:
    """ROS's image_geometry and OpenCV read an empty D (``data: []``) as no distortion, and
    StereoRectifier took it so; the readers refused it ("has 0 coefficients")."""
    empty = np.zeros(0)
    lp, rp = ros_pair(tmp_path, {"d": empty}, {"d": empty})
    c = read_stereo_calibration(lp, second_path=rp)
    assert c.distortion_model == "plumb_bob"
    np.testing.assert_array_equal(c.D1, np.zeros(5))
    np.testing.assert_array_equal(c.D2, np.zeros(5))
    text = opencv_yaml(stereo_entries(D1=None, D2=None)) + "D1: []\nD2: []\n"
    c = read_stereo_calibration(write(tmp_path / "e.yml", text), translation_unit="mm")
    np.testing.assert_array_equal(c.D1, np.zeros(5))
    # OpenCV writes an empty Mat as rows: 0, cols: 0 (refused as "shape (0, 0)")
    text = opencv_yaml(stereo_entries(D1=np.zeros((0, 0)), D2=np.zeros((0, 0))))
    assert "rows: 0" in text
    c = read_stereo_calibration(write(tmp_path / "m.yml", text), translation_unit="mm")
    np.testing.assert_array_equal(c.D2, np.zeros(5))
    # A fisheye model's zeros are the equidistant projection, not a pinhole: still refused.
    lp, rp = ros_pair(
        tmp_path, {"d": empty, "model": "equidistant"}, {"d": empty, "model": "equidistant"}
    )
    with pytest.raises(ValueError, match=r"distortion_coefficients has 0 coefficients"):
        read_stereo_calibration(lp, second_path=rp)
