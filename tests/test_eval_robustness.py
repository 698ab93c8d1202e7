"""``stereodepth eval`` on damaged or unusual inputs: .npy files whose size disagrees with
their header; OpenCV's error messages kept whole, on one line."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import cli

PIL_Image = pytest.importorskip("PIL.Image")


def textured_pair(height: int, width: int, shift: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random grey texture, the right image the left one moved ``shift`` px to the left."""
    rng = np.random.default_rng(seed)
    texture = rng.integers(0, 256, (height, width + shift), dtype=np.uint8)
    return np.ascontiguousarray(texture[:, :width]), np.ascontiguousarray(texture[:, shift:])


def write_scene(folder: Path, left: np.ndarray, right: np.ndarray, disparity: float) -> Path:
    """Our layout: left.png, right.png (16-bit when the arrays are uint16), disp_gt.npy
    (``disparity`` everywhere) and mask_nonocc.npy (all true)."""
    folder.mkdir(parents=True)
    for name, image in (("left.png", left), ("right.png", right)):
        if image.dtype == np.uint16:
            stereodepth.io.write_png16(folder / name, image)
        else:
            PIL_Image.fromarray(image).save(folder / name)
    np.save(folder / "disp_gt.npy", np.full(left.shape[:2], disparity, np.float32))
    np.save(folder / "mask_nonocc.npy", np.ones(left.shape[:2], bool))
    return folder


def run_eval(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = cli.main(["eval", *argv])
    out, err = capsys.readouterr()
    return status, out, err


@pytest.fixture
def scene(tmp_path: Path) -> Path:
    left, right = textured_pair(64, 128, 5, seed=1)
    return write_scene(tmp_path / "scenes" / "s1", left, right, 5.0)


# --------------------------------------------------------------------------------------------
# .npy files whose size disagrees with their header


def damaged(content: bytes, fault: str) -> bytes:
    """A copy of the .npy file ``content`` (version 1.0, shape (64, 128)) with ``fault``."""
    from numpy.lib import format as npy

    header_end = content.index(b"\n") + 1
    if fault == "truncated":
        return content[:-100]
    if fault == "padded":
        return content + b"\0" * 100
    if fault == "header only":
        return content[:header_end]
    if fault == "huge shape":  # numpy allocated it: MemoryError
        buffer = io.BytesIO()
        dtype = np.load(io.BytesIO(content)).dtype
        header = {"descr": npy.dtype_to_descr(dtype), "fortran_order": False}
        npy.write_array_header_1_0(buffer, {**header, "shape": (10**6, 10**6)})
        return buffer.getvalue() + content[header_end:]
    assert fault == "damaged header"  # numpy raised tokenize's TokenError
    bad = content.replace(b"(64, 128), }", b"(64, 128 , }")
    assert bad != content and len(bad) == len(content)
    return bad


NPY_FAULTS = [
    ("truncated", "truncated: its header gives {dtype} (64, 128), {size} bytes of data, but "
     "the file holds {short} bytes after its 128-byte header"),
    ("padded", "followed by 100 stray byte(s): its header gives {dtype} (64, 128), {size} bytes "
     "of data, but the file holds {long} bytes"),
    ("header only", "truncated: its header gives {dtype} (64, 128), {size} bytes of data, but "
     "the file holds 0 bytes"),
    ("huge shape", "truncated: its header gives {dtype} (1000000, 1000000)"),
    ("damaged header", "not a readable .npy array (its header: "),
]  # fmt: skip


@pytest.mark.parametrize("name", ["disp_gt.npy", "mask_nonocc.npy"])
@pytest.mark.parametrize(("fault", "fragment"), NPY_FAULTS)
def test_npy_whose_size_disagrees_with_its_header_is_refused(
    scene: Path, capsys: pytest.CaptureFixture[str], name: str, fault: str, fragment: str
) -> None:
    """A padded .npy was read without a word, a damaged header raised TokenError and a
    damaged shape MemoryError (tracebacks), a truncated one gave numpy's words naming no
    size: one line naming the file, what its header gives and what the file holds."""
    path = scene / name
    content = path.read_bytes()
    dtype = np.load(path).dtype
    size = 64 * 128 * dtype.itemsize
    assert len(content) == 128 + size  # the header's length the fragments name
    path.write_bytes(damaged(content, fault))
    status, out, err = run_eval(capsys, str(scene), "--repeat", "1")
    assert status == 2 and out == "", err
    assert err.startswith("stereodepth eval: error: ") and err.count("\n") == 1, err
    want = fragment.format(dtype=dtype, size=size, short=size - 100, long=size + 100)
    assert f"{path}: " in err and want in err, err


def test_npy_of_the_right_size_is_read(scene: Path) -> None:
    """The check reads the header as numpy does: both format versions, either byte order."""
    from stereodepth.evaluation import _load_npy

    want = np.arange(64 * 128, dtype=">f8").reshape(64, 128)
    for version in ((1, 0), (2, 0)):
        path = scene / f"v{version[0]}.npy"
        with open(path, "wb") as f:
            np.lib.format.write_array(f, want, version=version)
        got = _load_npy(path)
        assert got.dtype == want.dtype and np.array_equal(got, want)
        with open(path, "ab") as f:
            f.write(b"\0")
        with pytest.raises(ValueError, match="followed by 1 stray byte"):
            _load_npy(path)


# --------------------------------------------------------------------------------------------
# OpenCV's errors


def opencv_error(call: Any) -> Any:
    """The cv2.error that ``call()`` raises (skips when this OpenCV does not raise)."""
    cv2 = pytest.importorskip("cv2")
    try:
        call()
    except cv2.error as exc:
        return exc
    pytest.skip("this OpenCV does not raise here")


def test_opencv_error_keeps_its_explanation_on_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """SGBM's error for images too narrow for the search range says why on its second line
    and gives the values on the next ones: only the last ("'...width/2' is 2") was kept."""
    cv2 = pytest.importorskip("cv2")
    left, right = textured_pair(32, 34, 5, seed=2)  # 34 - 32 disparities <= block size 5 // 2
    folder = write_scene(tmp_path / "narrow", left, right, 5.0)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=32, blockSize=5, P1=200, P2=800)
    exc = opencv_error(lambda: sgbm.compute(left, right))
    explanation = [line.lstrip(">").strip() for line in exc.err.strip().splitlines()]
    assert len(explanation) > 1  # the case: several lines
    status, out, err = run_eval(
        capsys, str(folder), "--method", "opencv-sgbm", "--num-disparities", "32", "--repeat", "1"
    )
    assert status == 2 and out == ""
    assert err.startswith("stereodepth eval: error: scene narrow: opencv-sgbm: opencv-sgbm ")
    assert err.count("\n") == 1, err
    for text in explanation:
        assert text and text in err, (text, err)
    assert f"({exc.code}:" in err and f"in function '{exc.func}'" in err
    assert exc.file not in err  # the source location left out


def test_opencv_message_forms() -> None:
    """One line each: the code, kind, check and function of a one-line error, without
    OpenCV's version and source file; the bindings' lines below it after ": "."""
    from stereodepth.evaluation import _cv_message

    cv2 = pytest.importorskip("cv2")
    grey16 = np.zeros((40, 60), np.uint16)
    exc = opencv_error(lambda: cv2.StereoBM_create(16, 9).compute(grey16, grey16))
    message = _cv_message(exc)
    assert "\n" not in message and exc.err.strip() in message
    assert message.startswith(f"({exc.code}:") and message.endswith(f"in function '{exc.func}'")
    assert exc.file not in message and not message.startswith("OpenCV")
    grey = np.zeros((40, 60), np.uint8)
    exc = opencv_error(lambda: cv2.StereoBM_create(16, 9).compute("left", grey))
    message = _cv_message(exc)
    assert "\n" not in message and message.startswith(f"({exc.code}:")
    for line in exc.err.strip().splitlines():
        assert line.lstrip(">").strip() in message
    assert _cv_message(ValueError("")) == "ValueError"
    assert _cv_message(ValueError(" one\n two ")) == "one: two"
