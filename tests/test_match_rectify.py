"""``stereodepth match --calib RAW.yaml``: a calibration of a raw (unrectified) pair makes the
command rectify the pair before matching (OpenCV FileStorage YAML written by cv2.FileStorage,
skipped without OpenCV). The raw pairs come from the generator of test_rectify_roundtrip.py
(``make_raw_pair``: a known lens distortion and small rotations applied to a rectified pair),
on the package's sample pair and on a shared scene (skipped when absent). The disparity must
be block_match of ``StereoRectifier.rectify`` of the raw pair and the depth
``disparity_to_depth`` with ``rectifier.rig``, bit for bit; plus the bad inputs: one line,
exit status 2."""

from __future__ import annotations

import importlib.util
import json
import sys
import types
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

pytest.importorskip("PIL", reason="reading images needs Pillow (the batch extra)")

from PIL import Image

from stereodepth import block_match, disparity_to_depth
from stereodepth.calib import read_stereo_calibration
from stereodepth.cli import main
from stereodepth.io import read_disparity_pfm, read_image
from stereodepth.match_pair import default_num_disparities
from stereodepth.rectify import StereoRectifier
from stereodepth.sample import sample_pair


def generator() -> ModuleType:
    """tests/test_rectify_roundtrip.py as a module, for its documented ``make_raw_pair``
    (pytest imports test files with importlib, so they cannot import each other by name)."""
    path = Path(__file__).with_name("test_rectify_roundtrip.py")
    spec = importlib.util.spec_from_file_location("_rectify_roundtrip_generator", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_opencv_yaml(path: Path, calib: Any, *, stored: bool) -> Path:
    """The calibration as cv2.FileStorage YAML, translations in millimetres (so the command
    needs ``--translation-unit mm``); with the generator's R1, R2, P1, P2 when ``stored``."""
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    mm = np.diag([1.0, 1.0, 1.0, 1000.0])
    fields = {
        "M1": calib.K1,
        "D1": calib.D1.reshape(1, -1),
        "M2": calib.K2,
        "D2": calib.D2.reshape(1, -1),
        "R": calib.R,
        "T": 1000.0 * calib.T.reshape(3, 1),
    }
    if stored:
        fields.update({"R1": calib.R1, "R2": calib.R2, "P1": calib.P1, "P2": calib.P2 @ mm})
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in fields.items():
        fs.write(key, np.asarray(value, dtype=np.float64))
    fs.write("imageSize", tuple(int(v) for v in calib.image_size))
    fs.release()
    return path


def run(capsys: pytest.CaptureFixture[str], *args: Any) -> tuple[int, str, str]:
    code = main(["match", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal bit for bit, NaN where NaN."""
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def raw_files(tmp: Path, left: np.ndarray, right: np.ndarray) -> tuple[Path, Path, Any]:
    raw_l, raw_r, calib, _ = generator().make_raw_pair(left, right)
    Image.fromarray(raw_l).save(tmp / "raw-left.png")
    Image.fromarray(raw_r).save(tmp / "raw-right.png")
    return tmp / "raw-left.png", tmp / "raw-right.png", calib


def check_outputs(
    out: Path, summary: dict[str, Any], calib_path: Path, left: Path, right: Path, **read: Any
) -> StereoRectifier:
    """The command's outputs against the library's steps done by hand (``read``: the reader's
    options, default translation_unit="mm")."""
    read.setdefault("translation_unit", "mm")
    rect = StereoRectifier.from_calibration(read_stereo_calibration(calib_path, **read))
    rect_l, rect_r = rect.rectify(read_image(left), read_image(right))
    h, w = rect_l.shape[:2]
    expected = block_match(rect_l, rect_r, num_disparities=default_num_disparities(w))
    disparity = read_disparity_pfm(out / "disparity.pfm")
    assert same(disparity, expected)
    rig = rect.rig
    depth = np.load(out / "depth.npy")
    assert same(
        depth,
        disparity_to_depth(
            disparity,
            focal_px=rig.focal_px,
            baseline_m=rig.baseline_mm / 1000.0,
            doffs_px=rig.doffs_px,
        ),
    )
    assert same(read_image(out / "left-rectified.png"), rect_l)
    assert same(read_image(out / "right-rectified.png"), rect_r)
    assert summary["rectified"] is True
    assert summary["rectified_size"] == [w, h] and summary["raw_size"] == [w, h]
    assert summary["rig"] == {
        "focal_px": rig.focal_px,
        "baseline_m": rig.baseline_mm / 1000.0,
        "doffs_px": rig.doffs_px,
    }
    second = read.get("second_path")
    assert summary["calibration"] == str(calib_path) + ("" if second is None else f", {second}")
    assert (out / "points.ply").stat().st_size > 0
    return rect


@pytest.mark.parametrize("stored", [True, False], ids=["stored-R1-P1", "bouguet"])
def test_raw_yaml_rectifies_then_matches(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stored: bool
) -> None:
    s = sample_pair(160, 96)
    left, right, calib = raw_files(tmp_path, s.left, s.right)
    yaml = write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=stored)
    out = tmp_path / "out"
    code, text, err = run(
        capsys, left, right, "--calib", yaml, "--translation-unit", "mm", "-o", f"{out}/",
        "--write-rectified", "--ply", "--no-preview", "--json",
    )  # fmt: skip
    assert code == 0, err
    rect = check_outputs(out, json.loads(text), yaml, left, right)
    # The generator's baseline, 0.1 m, read in millimetres.
    assert rect.rig.baseline_mm == pytest.approx(100.0, rel=1e-9)
    if stored:  # the file's own transforms are used as they are
        np.testing.assert_array_equal(rect.P1, calib.P1)


def test_text_summary_says_rectified(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    s = sample_pair(96, 64)
    left, right, calib = raw_files(tmp_path, s.left, s.right)
    yaml = write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=True)
    code, text, err = run(
        capsys, left, right, "--calib", yaml, "--translation-unit", "mm", "-o",
        f"{tmp_path}/p-", "--no-preview",
    )  # fmt: skip
    assert code == 0, err
    row = next(line for line in text.splitlines() if line.startswith("rectified"))
    assert "96x64 to 96x64 px" in row and "rectified left camera" in row
    assert (tmp_path / "p-depth.npy").exists() and not (tmp_path / "p-left-rectified.png").exists()


@pytest.mark.data
def test_raw_scene_round_trip(
    stereo_data_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = stereo_data_dir / "mb2003-teddy"
    if not scene.is_dir():
        pytest.skip("mb2003-teddy not in the shared data")
    orig_l, orig_r = read_image(scene / "left.png"), read_image(scene / "right.png")
    left, right, calib = raw_files(tmp_path, orig_l, orig_r)
    yaml = write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=True)
    out = tmp_path / "out"
    code, text, err = run(
        capsys, left, right, "--calib", yaml, "--translation-unit", "mm", "-o", f"{out}/",
        "--write-rectified", "--ply", "--no-preview", "--json",
    )  # fmt: skip
    assert code == 0, err
    check_outputs(out, json.loads(text), yaml, left, right)
    # Rectified back, the scene is itself again (up to resampling, away from the borders).
    back = read_image(out / "left-rectified.png").astype(np.int16)
    inner = (slice(20, -20), slice(20, -20))
    assert np.median(np.abs(back[inner] - orig_l.astype(np.int16)[inner])) <= 2


def ros_camera_info(
    path: Path,
    K: np.ndarray,
    D: np.ndarray,
    R: np.ndarray,
    P: np.ndarray,
    size: tuple[int, int],
) -> Path:
    """One camera as a ROS camera_info YAML file (translations in metres)."""

    def matrix(name: str, a: np.ndarray) -> str:
        a = np.atleast_2d(a)
        data = ", ".join(repr(float(v)) for v in a.ravel())
        return f"{name}:\n  rows: {a.shape[0]}\n  cols: {a.shape[1]}\n  data: [{data}]\n"

    path.write_text(
        f"image_width: {size[0]}\nimage_height: {size[1]}\ncamera_name: {path.stem}\n"
        + matrix("camera_matrix", K)
        + "distortion_model: plumb_bob\n"
        + matrix("distortion_coefficients", D)
        + matrix("rectification_matrix", R)
        + matrix("projection_matrix", P)
    )
    return path


def test_ros_camera_info_pair(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(128, 80)
    left, right, c = raw_files(tmp_path, s.left, s.right)
    ros_l = ros_camera_info(tmp_path / "left.yaml", c.K1, c.D1, c.R1, c.P1, c.image_size)
    ros_r = ros_camera_info(tmp_path / "right.yaml", c.K2, c.D2, c.R2, c.P2, c.image_size)
    out = tmp_path / "out"
    code, text, err = run(
        capsys, left, right, "--calib", ros_l, "--calib-right", ros_r, "-o", f"{out}/",
        "--write-rectified", "--ply", "--no-preview", "--json",
    )  # fmt: skip
    assert code == 0, err
    rect = check_outputs(
        out, json.loads(text), ros_l, left, right, second_path=ros_r, translation_unit="m"
    )
    assert rect.rig.baseline_mm == pytest.approx(100.0, rel=1e-9)


def kalibr_camchain(path: Path, calib: Any) -> Path:
    """The calibration as a Kalibr camchain (pinhole, radtan k1 k2 r1 r2; metres)."""

    def numbers(a: Any) -> str:
        return "[" + ", ".join(repr(float(v)) for v in np.ravel(a)) + "]"

    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = calib.R, calib.T
    text = ""
    for n, (K, D) in enumerate(((calib.K1, calib.D1), (calib.K2, calib.D2))):
        assert D[4] == 0  # radtan has no k3
        text += (
            f"cam{n}:\n  camera_model: pinhole\n"
            f"  intrinsics: {numbers([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])}\n"
            f"  distortion_model: radtan\n  distortion_coeffs: {numbers(D[:4])}\n"
            f"  resolution: [{calib.image_size[0]}, {calib.image_size[1]}]\n"
        )
        if n == 1:
            text += "  T_cn_cnm1:\n" + "".join(f"  - {numbers(row)}\n" for row in pose)
    path.write_text(text)
    return path


def test_kalibr_camchain(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(128, 80)
    left, right, c = raw_files(tmp_path, s.left, s.right)
    chain = kalibr_camchain(tmp_path / "camchain.yaml", c)
    out = tmp_path / "out"
    code, text, err = run(
        capsys, left, right, "--calib", chain, "-o", f"{out}/",
        "--write-rectified", "--ply", "--no-preview", "--json",
    )  # fmt: skip
    assert code == 0, err
    rect = check_outputs(out, json.loads(text), chain, left, right, translation_unit="m")
    assert rect.rig.baseline_mm == pytest.approx(100.0, rel=1e-9)


# --- bad input: one line, exit 2 ------------------------------------------------------------------


def _vertical_rig_files(tmp_path: Path) -> tuple[Any, np.ndarray, np.ndarray, Path]:
    """The sample pair (96 x 64) transposed, saved as up.png and down.png (64 wide, 96 tall),
    and the calibration of that rectified vertical rig (second camera below the first)."""
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(96, 64)
    up, down = (np.ascontiguousarray(np.swapaxes(a, 0, 1)) for a in (s.left, s.right))
    Image.fromarray(up).save(tmp_path / "up.png")
    Image.fromarray(down).save(tmp_path / "down.png")
    h, w = up.shape[:2]
    K = np.array([[100.0, 0, (w - 1) / 2], [0, 100.0, (h - 1) / 2], [0, 0, 1]])
    c = types.SimpleNamespace(
        K1=K, D1=np.zeros(5), K2=K, D2=np.zeros(5), R=np.eye(3), T=np.array([0, -0.1, 0]),
        image_size=(w, h),
    )  # fmt: skip
    return s, up, down, write_opencv_yaml(tmp_path / "vertical.yml", c, stored=False)


@pytest.mark.parametrize("method", ["bm", "sgm"])
def test_a_vertical_rigs_error_speaks_of_its_height(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], method: str
) -> None:
    """The matchers' errors are about the pair they match, which for a vertical rig is the
    transposed one: a search range beyond the 96 px tall (64 px wide) images was refused as
    lying outside "an image 96 pixels wide". The message now says which side that is."""
    _, up, _, yaml = _vertical_rig_files(tmp_path)
    assert up.shape[:2] == (96, 64)
    code, text, err = run(
        capsys, tmp_path / "up.png", tmp_path / "down.png", "--calib", yaml,
        "--translation-unit", "mm", "--num-disparities", "16", "--min-disparity", "96",
        "--method", method, "-o", f"{tmp_path / 'out'}/", "--no-preview",
    )  # fmt: skip
    assert code == 2 and text == ""
    assert err.count("\n") == 1, err
    assert "inside an image 96 pixels wide" in err
    assert "a vertical rig: the pair is matched transposed" in err
    assert "the rectified images' height of 96 pixels" in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_vertical_rig_is_matched_along_its_columns(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A rig with the second camera below the first: the sample pair transposed is exactly
    such a pair, already rectified (R = I, T along -y, no distortion: the maps are the
    identity), so match must give the transposed disparity of the horizontal pair, and depth
    f B / d in the vertical pair's own orientation."""
    s, up, down, yaml = _vertical_rig_files(tmp_path)
    h, w = up.shape[:2]
    out = tmp_path / "out"
    code, text, err = run(
        capsys, tmp_path / "up.png", tmp_path / "down.png", "--calib", yaml,
        "--translation-unit", "mm", "--num-disparities", "32", "--disparity-format", "pfm",
        "-o", f"{out}/", "--no-preview", "--json",
    )  # fmt: skip
    assert code == 0, err
    rect = StereoRectifier.from_file(yaml, translation_unit="mm")
    assert rect.vertical
    assert all(same(a, b) for a, b in zip(rect.rectify(up, down), (up, down), strict=True))
    expected = block_match(s.left, s.right, num_disparities=32).T
    disparity = read_disparity_pfm(out / "disparity.pfm")
    assert disparity.shape == (h, w) and same(disparity, np.ascontiguousarray(expected))
    depth = np.load(out / "depth.npy")
    ok = np.isfinite(disparity)
    assert ok.mean() > 0.5
    np.testing.assert_allclose(depth[ok], 100.0 * 0.1 / disparity[ok], rtol=1e-6)
    assert json.loads(text)["rectified"] is True


def test_bad_input_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(96, 64)
    left, right, c = raw_files(tmp_path, s.left, s.right)
    yaml = write_opencv_yaml(tmp_path / "stereo.yml", c, stored=False)
    # The second camera above the first: its disparities are negative.
    upside = c.__class__(**{**c.__dict__, "R": np.eye(3), "T": np.array([0, 0.1, 0])})
    upside_yaml = write_opencv_yaml(tmp_path / "upside.yml", upside, stored=False)
    swapped = c.__class__(**{**c.__dict__, "R": c.R.T, "T": -c.R.T @ c.T})
    swapped_yaml = write_opencv_yaml(tmp_path / "swapped.yml", swapped, stored=False)
    ros = ros_camera_info(tmp_path / "left.yaml", c.K1, c.D1, c.R1, c.P1, c.image_size)
    (tmp_path / "garbage.yml").write_text("stereo: [1, 2\n")
    (tmp_path / "partial.yml").write_text("%YAML:1.0\n---\nM1: [1, 2, 3]\n")
    middlebury = tmp_path / "calib.txt"
    middlebury.write_text(
        "cam0=[96 0 47.5; 0 96 31.5; 0 0 1]\ncam1=[96 0 47.5; 0 96 31.5; 0 0 1]\n"
        "doffs=0\nbaseline=100\nwidth=96\nheight=64\n"
    )
    Image.fromarray(np.zeros((48, 80), np.uint8)).save(tmp_path / "small.png")
    small = tmp_path / "small.png"
    cases: list[tuple[list[Any], str]] = [
        (["--calib", yaml, "--translation-unit", "mm", "--no-rectify"], "--no-rectify forbids"),
        (["--calib", yaml], "T is 100 long: read as metres (no translation unit given) that"),
        (["--calib", yaml], "give its unit with --translation-unit, e.g. 'mm', or 'm' to"),
        (["--calib", ros], "pass the right camera's file as --calib-right"),
        (["--calib", tmp_path / "garbage.yml"], "not a calibration file this reader knows"),
        (["--calib", tmp_path / "partial.yml"], "partial.yml"),
        (["--calib", yaml, "--translation-unit", "mm", "--focal-px", "9"], "not both"),
        (["--calib", upside_yaml, "--translation-unit", "mm"], "first camera is below the"),
        (["--calib", swapped_yaml, "--translation-unit", "mm"], "first camera is right of the"),
        (["--calib", middlebury, "--calib-right", ros], "--calib-right does not apply"),
        (["--calib", middlebury, "--write-rectified"], "--write-rectified does not apply"),
        (["--calib", middlebury, "--translation-unit", "mm"], "--translation-unit does not"),
        (["--no-rectify"], "--no-rectify goes with --calib FILE"),
        (["--calib-right", ros], "--calib-right goes with --calib FILE"),
        (["--alpha", "0.5"], "--alpha goes with --calib FILE"),
        (["--distortion-model", "plumb_bob"], "--distortion-model goes with --calib FILE"),
        (["--calib", middlebury, "--distortion-model", "plumb_bob"], "--distortion-model does"),
        (
            ["--calib", ros, "--calib-right", ros, "--distortion-model", "plumb_bob"],
            "--distortion-model does not apply to a ROS camera_info file",
        ),
        (["--calib", middlebury, "--alpha", "0"], "--alpha does not apply"),
        # A fault of the second file is named as --calib-right's, not --calib's.
        (["--calib", ros, "--calib-right", tmp_path / "garbage.yml"], "error: --calib-right: "),
        (
            ["--calib", yaml, "--translation-unit", "mm", "--alpha", "-0.5"],
            "--alpha must be -1 (OpenCV's default scaling)",
        ),
    ]
    for args, message in cases:
        code, out, err = run(capsys, left, right, *args)
        assert code == 2, (args, err)
        assert out == ""
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("stereodepth match: error: "), err
        assert message in lines[0], (message, err)
        assert "Traceback" not in err
    code, out, err = run(
        capsys, small, small, "--calib", yaml, "--translation-unit", "mm", "-o", f"{tmp_path}/x-"
    )
    assert code == 2 and "size of the calibration in --calib, 96x64 px, got 80x48" in err, err
    assert not list(tmp_path.glob("x-*")) and not list(Path.cwd().glob("disparity*"))


def turned_180(calib: Any) -> Any:
    """The calibration of the same two cameras with their images turned by 180 degrees: each
    camera's frame turned about its axis (x and y negated), so cx, cy mirror, the tangential
    distortion changes sign, R becomes Rz R Rz and T Rz T."""
    w, h = calib.image_size
    rz = np.diag([-1.0, -1.0, 1.0])

    def k(m: np.ndarray) -> np.ndarray:
        m = m.copy()
        m[0, 2], m[1, 2] = w - 1 - m[0, 2], h - 1 - m[1, 2]
        return m

    def d(v: np.ndarray) -> np.ndarray:
        v = v.copy().ravel()
        v[2:4] = -v[2:4]  # p1, p2
        return v

    return calib.__class__(
        **{
            **calib.__dict__,
            **{"K1": k(calib.K1), "K2": k(calib.K2), "D1": d(calib.D1), "D2": d(calib.D2)},
            **{"R": rz @ calib.R @ rz, "T": rz @ calib.T},
        }
    )


def test_a_rig_calibrated_upside_down_is_told_what_happened_and_what_to_do(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A rig rolled by 180 degrees (both cameras upside down) and calibrated so, its cameras
    named by their side in the world: camera 1 is the rig's right camera (b), now on the
    world's left, and in its own, turned, frame the other is on its left. That calibration is
    the rig's with the cameras swapped (R.T, -R.T @ T). The refusal said "swap the cameras:
    the calibration's camera 1 and camera 2", which a user did with K1, K2 and D1, D2 alone:
    refused the same. It now gives the T received, OpenCV's convention and the complete swap
    (R by R.T, T by -R.T @ T), in one short line; K and D swapped alone are still refused,
    the complete swap matches, and so does the other remedy for an upside-down rig (the
    images turned by 180 degrees and calibrated again), whose outputs are upright."""
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(160, 96)
    a, b, c = raw_files(tmp_path, s.left, s.right)  # a: the rig's left camera, b: its right
    assert np.abs(c.R - np.eye(3)).max() > 1e-3  # R.T is not R: the swap must turn it
    # Camera 1 is the rig's right one (b), on the world's left when the rig is upside down.
    swap = {"K1": c.K2, "D1": c.D2, "K2": c.K1, "D2": c.D1, "R": c.R.T, "T": -c.R.T @ c.T}
    world = c.__class__(**{**c.__dict__, **swap})
    upside = write_opencv_yaml(tmp_path / "upside.yml", world, stored=False)
    kd = {"K1": world.K2, "D1": world.D2, "K2": world.K1, "D2": world.D1}
    kd_only = write_opencv_yaml(tmp_path / "kd.yml", c.__class__(**{**world.__dict__, **kd}),
                                stored=False)  # fmt: skip
    t = ", ".join(f"{v + 0.0:.6g}" for v in world.T)
    for left, right, calib in ((b, a, upside), (a, b, upside), (a, b, kd_only)):
        mm = ("--calib", calib, "--translation-unit", "mm", "--no-preview", "--json")
        code, out, err = run(capsys, left, right, *mm, "-o", f"{tmp_path}/x/")
        assert (code, out) == (2, ""), err
        assert err.count("\n") == 1 and "first camera is right of the second" in err
        message = err.split(f"{calib}: ", 1)[1].strip()
        assert len(message) < 320, message  # about 700 before
        assert message.startswith(f"the first camera is right of the second: T = [{t}] m")
        assert "OpenCV's x2 = R @ x1 + T gives T[0] < 0 when the left camera is first" in err
        assert "If T's sign is wrong, negate it" in err
        assert "swap K1/K2 and D1/D2 and replace R by R.T, T by -R.T @ T" in err
        assert message.endswith("Give the left image first")
        assert not (tmp_path / "x").exists()
    # The remedies: the complete swap as the message gives it, with the left image first; or
    # the images turned (upright outputs for an upside-down rig).
    complete = {"R": world.R.T, "T": -world.R.T @ world.T}
    fixed = c.__class__(**{**world.__dict__, **kd, **complete})
    np.testing.assert_allclose(fixed.T, c.T, atol=1e-15)
    fixed_yaml = write_opencv_yaml(tmp_path / "fixed.yml", fixed, stored=False)
    turned = write_opencv_yaml(tmp_path / "turned.yml", turned_180(world), stored=False)
    for name, arr in (("b180.png", read_image(b)), ("a180.png", read_image(a))):
        Image.fromarray(np.ascontiguousarray(arr[::-1, ::-1])).save(tmp_path / name)
    for left, right, calib in (
        (a, b, fixed_yaml),
        (tmp_path / "b180.png", tmp_path / "a180.png", turned),
    ):
        code, out, err = run(
            capsys, left, right, "--calib", calib, "--translation-unit", "mm", "--no-preview",
            "--json", "-o", f"{tmp_path}/{calib.stem}/",
        )  # fmt: skip
        assert code == 0, err
        assert json.loads(out)["density"] > 0.5


def test_a_hand_written_t_of_the_wrong_sign_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The likeliest cause of a first camera on the right: an OpenCV YAML written by hand with
    K1 = K2, D = 0, R = I and T = [+baseline, 0, 0], where OpenCV's x2 = R x1 + T wants
    T[0] = -baseline for a left-first rig. The refusal did not name it; it now gives the T
    received and the convention, and the negated T matches."""
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(96, 64)
    Image.fromarray(s.left).save(tmp_path / "left.png")
    Image.fromarray(s.right).save(tmp_path / "right.png")

    def matrix(rows: int, cols: int, data: list[float]) -> str:
        values = ", ".join(repr(float(v)) for v in data)
        return f"!!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [{values}]"

    def calibration(name: str, tx: float) -> Path:
        k = matrix(3, 3, [100, 0, 47.5, 0, 100, 31.5, 0, 0, 1])
        d = matrix(1, 5, [0] * 5)
        identity = matrix(3, 3, [1, 0, 0, 0, 1, 0, 0, 0, 1])
        fields = {"K1": k, "D1": d, "K2": k, "D2": d, "R": identity, "T": matrix(3, 1, [tx, 0, 0])}
        text = "".join(f"{key}: {value}\n" for key, value in fields.items())
        path = tmp_path / name
        path.write_text(f"%YAML:1.0\n---\n{text}imageSize: [96, 64]\n")
        return path

    left, right = tmp_path / "left.png", tmp_path / "right.png"
    flags = ("--num-disparities", "32", "--no-preview", "--json")
    swapped = calibration("swapped.yml", 0.17)
    code, out, err = run(capsys, left, right, "--calib", swapped, *flags, "-o", f"{tmp_path}/x/")
    assert (code, out) == (2, ""), err
    assert err == (
        f"stereodepth match: error: --calib: {swapped}: the first camera is right of the "
        "second: T = [0.17, 0, 0] m, and OpenCV's x2 = R @ x1 + T gives T[0] < 0 when the left "
        "camera is first. If T's sign is wrong, negate it; if the cameras are named the other "
        "way, swap K1/K2 and D1/D2 and replace R by R.T, T by -R.T @ T. Give the left image "
        "first\n"
    )
    fixed = calibration("fixed.yml", -0.17)
    code, out, err = run(capsys, left, right, "--calib", fixed, *flags, "-o", f"{tmp_path}/y/")
    assert code == 0, err
    assert json.loads(out)["density"] > 0.5


def test_split_opencv_files_without_a_size_take_image_size(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """OpenCV's stereo_calib sample writes intrinsics.yml and extrinsics.yml with no image
    size: the command said "pass image_size=(width, height)", a keyword no flag gave."""
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    s = sample_pair(96, 64)
    left, right, c = raw_files(tmp_path, s.left, s.right)
    parts = {
        "intrinsics.yml": {"M1": c.K1, "D1": c.D1, "M2": c.K2, "D2": c.D2},
        "extrinsics.yml": {"R": c.R, "T": 1000.0 * c.T},
    }
    for name, fields in parts.items():
        fs = cv2.FileStorage(str(tmp_path / name), cv2.FILE_STORAGE_WRITE)
        for key, value in fields.items():
            fs.write(key, np.asarray(value, dtype=np.float64))
        fs.release()
    files = ("--calib", tmp_path / "intrinsics.yml", "--calib-right", tmp_path / "extrinsics.yml")
    flags = (*files, "--translation-unit", "mm", "--no-preview", "--json")
    code, out, err = run(capsys, left, right, *flags, "-o", f"{tmp_path}/a-")
    assert code == 2 and "no image size in the file" in err, err
    assert "pass --image-size WIDTH HEIGHT" in err and "image_size=" not in err, err
    code, out, err = run(
        capsys, left, right, *flags, "--image-size", "96", "64", "-o", f"{tmp_path}/b-"
    )
    assert code == 0, err
    want = StereoRectifier.from_file(
        tmp_path / "intrinsics.yml",
        second_path=tmp_path / "extrinsics.yml",
        translation_unit="mm",
        image_size=(96, 64),
    )
    assert json.loads(out)["rig"]["focal_px"] == want.rig.focal_px
    code, out, err = run(capsys, left, right, *flags, "--image-size", "0", "64")
    assert code == 2 and "--image-size must be two whole numbers > 0, got (0, 64)" in err, err
    code, out, err = run(capsys, left, right, "--image-size", "96", "64")
    assert code == 2 and "--image-size goes with --calib FILE" in err, err


def test_four_coefficients_need_a_model(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An OpenCV file with 4 distortion coefficients and no distortion_model: cv2.fisheye's
    k1..k4 or plumb_bob's k1 k2 p1 p2. It was read as the latter, so a fisheye calibration
    rectified its pair wrongly without a word; now --distortion-model (or the file) says."""
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(96, 64)
    left, right, c = raw_files(tmp_path, s.left, s.right)
    d = np.array([0.05, -0.01, 0.002, -0.0004])
    fish = c.__class__(**{**c.__dict__, "D1": d, "D2": d})
    yaml = write_opencv_yaml(tmp_path / "fish.yml", fish, stored=False)
    code, out, err = run(capsys, left, right, "--calib", yaml, "--translation-unit", "mm")
    assert code == 2 and out == "", err
    assert "fish.yml: D1 has 4 coefficients" in err and "say which with --distortion-model" in err
    focal = {}
    for model in ("equidistant", "plumb_bob"):
        flags = ("--translation-unit", "mm", "--distortion-model", model, "--json")
        code, out, err = run(
            capsys,
            left,
            right,
            "--calib",
            yaml,
            *flags,
            "--no-preview",
            "-o",
            f"{tmp_path}/{model}-",
        )
        assert code == 0, err
        want = StereoRectifier.from_file(yaml, translation_unit="mm", distortion_model=model)
        focal[model] = json.loads(out)["rig"]["focal_px"]
        assert focal[model] == want.rig.focal_px
    assert focal["equidistant"] != focal["plumb_bob"]  # the model is the one asked for
    # --alpha with a fisheye file: the message named "alpha" and the balance and fov_scale
    # keywords, which no flag gives.
    flags = ("--translation-unit", "mm", "--distortion-model", "equidistant", "--alpha", "0")
    code, out, err = run(capsys, left, right, "--calib", yaml, *flags, "--no-preview")
    assert code == 2 and err.count("\n") == 1, err
    assert (
        "--alpha applies to pinhole calibrations; " + str(yaml) + " is an equidistant (fisheye)"
    ) in err and "drop --alpha" in err


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--method", "sgm", "--block-size", "5"], "--block-size 5: block_size must be 1 or 3"),
        (["--block-size", "4"], "--block-size 4: block_size must be an odd integer"),
        (["--cost", "sad", "--block-size", "33"], "--block-size 33: block_size must be an odd"),
        (["--num-disparities", "5000"], "--num-disparities 5000: num_disparities must be"),
        (["--min-disparity", "-99999"], "--min-disparity -99999: min_disparity must be"),
        (["--method", "sgm", "--cost", "sad"], "--cost: --method sgm has no cost, got 'sad'"),
    ],
)
def test_bad_matcher_flag_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], message: str
) -> None:
    """A matcher flag the matcher refuses is one line naming the flag as typed, before any
    file is written: the rectified pair of --write-rectified used to be written first and
    left behind."""
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(96, 64)
    left, right, c = raw_files(tmp_path, s.left, s.right)
    yaml = write_opencv_yaml(tmp_path / "stereo.yml", c, stored=False)
    out = tmp_path / "out"
    code, text, err = run(
        capsys, left, right, "--calib", yaml, "--translation-unit", "mm", "-o", f"{out}/",
        "--write-rectified", "--ply", "--no-preview", *flags,
    )  # fmt: skip
    assert code == 2 and text == ""
    assert err == f"stereodepth match: error: {err.split('error: ', 1)[1]}"
    assert len(err.strip().splitlines()) == 1 and message in err, err
    assert not out.exists() or not list(out.iterdir())


def test_yaml_calibration_without_pyyaml_is_a_missing_extra(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A YAML --calib without PyYAML is the missing-extra error of the README (the pip
    install, exit status 1) for match and batch alike; it was a usage error (status 2)."""
    s = sample_pair(96, 64)
    left, right, c = raw_files(tmp_path, s.left, s.right)
    ros = ros_camera_info(tmp_path / "left.yaml", c.K1, c.D1, c.R1, c.P1, c.image_size)
    monkeypatch.setitem(sys.modules, "yaml", None)
    want = (
        "error: --calib: reading YAML calibration files needs PyYAML: "
        'pip install "stereodepth[calib]"'
    )
    code, out, err = run(capsys, left, right, "--calib", ros, "-o", f"{tmp_path}/m/")
    assert (code, out) == (1, "") and err.strip() == f"stereodepth match: {want}"
    (tmp_path / "in").mkdir()
    left.rename(tmp_path / "in" / "left.png")
    right.rename(tmp_path / "in" / "right.png")
    argv = ["batch", str(tmp_path / "in"), "-o", str(tmp_path / "b"), "--calib", str(ros)]
    assert main([*argv, "--num-disparities", "16"]) == 1
    assert capsys.readouterr().err.strip() == f"stereodepth batch: {want}"
    assert not (tmp_path / "m").exists() and not (tmp_path / "b").exists()


def test_outputs_never_overwrite_the_inputs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Raw images named as the rectified outputs, matched with ``-o`` their own folder: the
    command overwrote the raw pair with its rectification. Now a usage error, nothing written."""
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(96, 64)
    left, right, c = raw_files(tmp_path, s.left, s.right)
    yaml = write_opencv_yaml(tmp_path / "stereo.yml", c, stored=False)
    left = left.rename(tmp_path / "left-rectified.png")
    right = right.rename(tmp_path / "right-rectified.png")
    before = {p: p.read_bytes() for p in (left, right)}
    code, out, err = run(
        capsys, left, right, "--calib", yaml, "--translation-unit", "mm", "--write-rectified",
        "--no-preview", "-o", f"{tmp_path}/",
    )  # fmt: skip
    assert (code, out) == (2, "") and err.count("\n") == 1
    assert f"--out: '{left}' would overwrite LEFT '{left}'" in err
    assert {p: p.read_bytes() for p in (left, right)} == before
    assert not (tmp_path / "disparity.pfm").exists()


def test_a_refused_file_with_its_own_rectification_is_told_to_compute_it_anew(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A file that also holds R1, R2, P1, P2 (as OpenCV's stereo_calib sample writes them),
    made from a T of the wrong sign: the rig is refused from those P's, and correcting T alone
    leaves them as they were, refused again. The message says so (delete them, or --alpha -1),
    and --alpha -1 with the corrected T matches."""
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    s = sample_pair(160, 96)
    a, b, c = raw_files(tmp_path, s.left, s.right)

    def with_own(calib: Any) -> Any:
        d1, d2 = (np.asarray(v, np.float64).reshape(1, -1) for v in (calib.D1, calib.D2))
        t = np.asarray(calib.T, np.float64).reshape(3, 1)
        r1, r2, p1, p2, *_ = cv2.stereoRectify(
            calib.K1, d1, calib.K2, d2, tuple(calib.image_size), calib.R, t, alpha=-1
        )
        return calib.__class__(**{**calib.__dict__, "R1": r1, "R2": r2, "P1": p1, "P2": p2})

    wrong = with_own(c.__class__(**{**c.__dict__, "T": -c.T}))
    negated_only = c.__class__(**{**wrong.__dict__, "T": c.T})  # T corrected, its P's not
    wrong_yaml = write_opencv_yaml(tmp_path / "wrong.yml", wrong, stored=True)
    negated_yaml = write_opencv_yaml(tmp_path / "negated.yml", negated_only, stored=True)
    hint = "this file also holds R1, R2, P1, P2, made from its R and T"
    for calib in (wrong_yaml, negated_yaml):
        mm = ("--calib", calib, "--translation-unit", "mm", "--no-preview", "--json")
        code, out, err = run(capsys, a, b, *mm, "-o", f"{tmp_path}/x/")
        assert (code, out) == (2, ""), err
        assert err.count("\n") == 1 and hint in err and "--alpha -1" in err
    mm = ("--calib", negated_yaml, "--translation-unit", "mm", "--no-preview", "--json")
    code, out, err = run(capsys, a, b, *mm, "--alpha", "-1", "-o", f"{tmp_path}/y/")
    assert code == 0, err
    assert json.loads(out)["density"] > 0.5


def test_matched_along_rows_annotates_only_a_vertical_rigs_errors() -> None:
    """The wrapper both commands put around matching (match, and batch's jobs): a horizontal
    rig's error passes through as it is, a vertical rig's names the side it is about, and other
    exceptions are not touched."""
    from stereodepth._calib_rule import matched_along_rows

    plain = r"^an image 64 pixels wide$"
    with pytest.raises(ValueError, match=plain), matched_along_rows(False, 96):
        raise ValueError("an image 64 pixels wide")
    noted = r"^an image 96 pixels wide \(a vertical rig: .* height of 96 pixels and their rows\)$"
    with pytest.raises(ValueError, match=noted), matched_along_rows(True, 96):
        raise ValueError("an image 96 pixels wide")
    with pytest.raises(TypeError, match=r"^num_disparities$"), matched_along_rows(True, 9):
        raise TypeError("num_disparities")
