"""stereodepth.io: reading images, writing PNG16 / PFM / npy atomically, and what a killed
writer leaves behind."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from stereodepth import io

Image = pytest.importorskip("PIL.Image")


def names(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir())


# --- read_image -------------------------------------------------------------------------------
def test_read_image_modes(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    grey = rng.integers(0, 256, (7, 9), dtype=np.uint8)
    rgb = rng.integers(0, 256, (7, 9, 3), dtype=np.uint8)
    g16 = rng.integers(0, 65536, (7, 9), dtype=np.uint16)
    Image.fromarray(grey).save(tmp_path / "g.png")
    Image.fromarray(rgb).save(tmp_path / "c.png")
    Image.fromarray(np.dstack([rgb, grey])).save(tmp_path / "a.png")  # RGBA
    io.write_png16(tmp_path / "w.png", g16)
    np.testing.assert_array_equal(io.read_image(tmp_path / "g.png"), grey, strict=True)
    np.testing.assert_array_equal(io.read_image(tmp_path / "c.png"), rgb, strict=True)
    np.testing.assert_array_equal(io.read_image(tmp_path / "a.png"), rgb, strict=True)
    np.testing.assert_array_equal(io.read_image(tmp_path / "w.png"), g16, strict=True)


def test_read_image_missing_and_corrupt(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"image not found: .*nope\.png"):
        io.read_image(tmp_path / "nope.png")
    good = tmp_path / "good.png"
    Image.fromarray(np.zeros((64, 64), np.uint8) + 7).save(good)
    data = good.read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    (tmp_path / "text.png").write_bytes(b"not an image at all")
    for bad in ("cut.png", "text.png"):
        with pytest.raises(ValueError, match=r"cannot decode image .*" + re.escape(bad)):
            io.read_image(tmp_path / bad)


# --- atomic_write -----------------------------------------------------------------------------
def test_atomic_write_replaces_only_on_success(tmp_path: Path) -> None:
    target = tmp_path / "out.bin"
    with io.atomic_write(target) as f:
        f.write(b"first")
        # while writing: a temporary file beside the target, the target not there yet
        assert not target.exists()
        assert len(names(tmp_path)) == 1 and names(tmp_path)[0].startswith(".out.bin.")
    assert target.read_bytes() == b"first"
    for exc in (RuntimeError("boom"), KeyboardInterrupt()):
        with pytest.raises(type(exc)):
            write_then_raise(target, exc)
        assert target.read_bytes() == b"first"
        assert names(tmp_path) == ["out.bin"]


def write_then_raise(target: Path, exc: BaseException) -> None:
    with io.atomic_write(target) as f:
        f.write(b"second, half written")
        raise exc


def test_atomic_write_text_and_permissions(tmp_path: Path) -> None:
    target = tmp_path / "t.json"
    old = os.umask(0o022)
    try:
        with io.atomic_write(target, text=True) as f:
            f.write("héllo\n")
    finally:
        os.umask(old)
    assert target.read_text(encoding="utf-8") == "héllo\n"
    assert target.stat().st_mode & 0o777 == 0o644  # as open() would make it, not mkstemp's 0600


def test_a_killed_writer_leaves_no_partial_file(tmp_path: Path) -> None:
    """SIGKILL in the middle of a write: the target keeps its old content, a temporary file
    remains, and remove_temp_files sweeps it (and nothing else)."""
    target = tmp_path / "depth.npy"
    target.write_bytes(b"old")
    (tmp_path / ".keep.tmp").write_bytes(b"not ours")
    script = textwrap.dedent(f"""
        import sys, time
        from stereodepth import io
        with io.atomic_write({str(target)!r}) as f:
            f.write(b"x" * 100000)
            f.flush()
            print("writing", flush=True)
            time.sleep(60)
    """)
    with subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, text=True
    ) as proc:
        try:
            assert proc.stdout is not None
            assert proc.stdout.readline().strip() == "writing"
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert target.read_bytes() == b"old"
    leftovers = [n for n in names(tmp_path) if n.startswith(".depth.npy.")]
    assert len(leftovers) == 1 and leftovers[0].endswith(".tmp")
    removed = io.remove_temp_files(tmp_path)
    assert [p.name for p in removed] == leftovers
    assert names(tmp_path) == [".keep.tmp", "depth.npy"]
    assert io.remove_temp_files(tmp_path / "absent") == []


# --- npy, PNG16 -------------------------------------------------------------------------------
def test_write_npy_exact_path(tmp_path: Path) -> None:
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    io.write_npy(tmp_path / "d.disparity.npy", a)
    io.write_npy(tmp_path / "noext", a)
    assert names(tmp_path) == ["d.disparity.npy", "noext"]
    np.testing.assert_array_equal(np.load(tmp_path / "noext"), a, strict=True)


def test_png16_compress_level(tmp_path: Path) -> None:
    a = (np.arange(64 * 64, dtype=np.uint16) // 7).reshape(64, 64)
    sizes = []
    for level in (0, 1, 9):
        io.write_png16(tmp_path / f"{level}.png", a, compress_level=level)
        np.testing.assert_array_equal(io.read_image(tmp_path / f"{level}.png"), a, strict=True)
        sizes.append((tmp_path / f"{level}.png").stat().st_size)
    assert sizes[0] > sizes[1] >= sizes[2]
    with pytest.raises(ValueError, match=r"compress_level must be an integer in \[0, 9\], got 10"):
        io.write_png16(tmp_path / "x.png", a, compress_level=10)
    with pytest.raises(TypeError, match=r"compress_level must be an integer, got 1\.5"):
        io.write_png16(tmp_path / "x.png", a, compress_level=1.5)  # type: ignore[arg-type]


def test_png16_round_trip_and_extremes(tmp_path: Path) -> None:
    a = np.array([[0, 1, 255, 256], [4095, 32768, 65534, 65535]], np.uint16)
    for shape in [(2, 4), (1, 1), (3, 1023)]:
        b = np.resize(a, shape)
        io.write_png16(tmp_path / "d.png", b)
        np.testing.assert_array_equal(io.read_image(tmp_path / "d.png"), b, strict=True)
    with Image.open(tmp_path / "d.png") as im:
        assert im.format == "PNG" and im.mode.startswith("I;16")


@pytest.mark.parametrize(
    ("array", "exc", "message"),
    [
        (np.zeros((2, 2), np.float32), TypeError, "array must have dtype uint16, got float32"),
        (
            np.zeros((2, 2, 3), np.uint16),
            ValueError,
            r"array must be a non-empty \(H, W\) array, got shape \(2, 2, 3\)",
        ),
        (np.zeros((0, 2), np.uint16), ValueError, r"got shape \(0, 2\)"),
        ([[1, 2]], TypeError, "array must be a numpy.ndarray, got list"),
    ],
)
def test_write_png16_rejects(tmp_path: Path, array: object, exc: type, message: str) -> None:
    with pytest.raises(exc, match=message):
        io.write_png16(tmp_path / "x.png", array)  # type: ignore[arg-type]
    assert names(tmp_path) == []


def test_disparity_png16_is_kitti_format(tmp_path: Path) -> None:
    d = np.array(
        [
            [0.0, 1.0, 10.5, 255.99],
            [np.nan, -3.0, np.inf, 300.0],
            [1 / 1024, 1 / 256, 100.00195, 2.5],
        ],
        np.float32,
    )
    io.write_disparity_png16(tmp_path / "d.png", d)
    raw = io.read_image(tmp_path / "d.png")
    assert raw.dtype == np.uint16
    want = [[0, 256, 2688, 65533], [0, 0, 0, 65535], [0, 1, 25600, 640]]
    assert raw.tolist() == want
    ok = raw > 0
    np.testing.assert_allclose(raw[ok] / 256, np.minimum(d[ok], 65535 / 256), atol=1 / 512)


# --- PFM --------------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", [(1, 1), (3, 5), (4, 7, 3), (1, 1023)])
def test_pfm_round_trip(tmp_path: Path, shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(1)
    a = rng.normal(size=shape).astype(np.float32)
    a.flat[0] = np.nan
    a.flat[-1] = np.inf
    io.write_pfm(tmp_path / "a.pfm", a)
    b = io.read_pfm(tmp_path / "a.pfm")
    assert b.dtype == np.float32 and b.flags.writeable
    np.testing.assert_array_equal(b, a, strict=True)
    io.write_pfm(tmp_path / "b.pfm", a.astype(np.float64))
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "b.pfm"), a, strict=True)


def test_pfm_layout_on_disk(tmp_path: Path) -> None:
    """Rows bottom to top, little-endian for a negative scale; big-endian files read too."""
    a = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], np.float32)
    io.write_pfm(tmp_path / "a.pfm", a)
    data = (tmp_path / "a.pfm").read_bytes()
    assert data.startswith(b"Pf\n3 2\n-1.0\n")
    assert np.frombuffer(data[len(b"Pf\n3 2\n-1.0\n") :], "<f4").tolist() == [4, 5, 6, 1, 2, 3]
    # Another writer's layout: one header line, big-endian
    (tmp_path / "be.pfm").write_bytes(b"Pf 3 2 1.0\n" + a[::-1].astype(">f4").tobytes())
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "be.pfm"), a, strict=True)


def test_read_pfm_rejects(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="PFM file not found"):
        io.read_pfm(tmp_path / "nope.pfm")
    (tmp_path / "magic.pfm").write_bytes(b"P6\n3 2\n255\n" + bytes(18))
    with pytest.raises(ValueError, match=r"magic\.pfm: not a PFM file"):
        io.read_pfm(tmp_path / "magic.pfm")
    (tmp_path / "cut.pfm").write_bytes(b"PF\n3 2\n-1\n" + bytes(40))
    with pytest.raises(
        ValueError,
        match=r"cut.pfm: truncated PFM: 3x2x3 needs 72 bytes of data, "
        r"got 40",
    ):
        io.read_pfm(tmp_path / "cut.pfm")
    (tmp_path / "zero.pfm").write_bytes(b"Pf\n1 1\n0\n" + bytes(4))
    with pytest.raises(ValueError, match=r"zero\.pfm: bad PFM scale 0"):
        io.read_pfm(tmp_path / "zero.pfm")


@pytest.mark.parametrize(
    ("array", "kwargs", "exc", "message"),
    [
        (np.zeros((2, 2), np.uint16), {}, TypeError, "array must have a float dtype, got uint16"),
        (
            np.zeros((2, 2, 2), np.float32),
            {},
            ValueError,
            r"array must have shape \(H, W\) or \(H, W, 3\), got \(2, 2, 2\)",
        ),
        (
            np.zeros((2, 2), np.float32),
            {"scale": 0.0},
            ValueError,
            "scale must be a finite number > 0, got 0.0",
        ),
    ],
)
def test_write_pfm_rejects(
    tmp_path: Path, array: np.ndarray, kwargs: dict[str, float], exc: type, message: str
) -> None:
    with pytest.raises(exc, match=message):
        io.write_pfm(tmp_path / "x.pfm", array, **kwargs)
    assert names(tmp_path) == []
