"""stereodepth.io: reading images, writing PNG16 / PFM / npy atomically, and what a killed
writer leaves behind."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereodepth import io
from stereodepth.pointcloud import write_ply

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


#: EXIF orientation -> the displayed image from the stored one (EXIF 2.32, tag 0x0112: where
#: the stored 0th row and 0th column are shown).
EXIF_UPRIGHT = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],  # mirrored left-right
    3: lambda a: a[::-1, ::-1],  # rotated 180
    4: lambda a: a[::-1],  # mirrored top-bottom
    5: lambda a: np.swapaxes(a, 0, 1),  # transposed
    6: lambda a: np.rot90(a, -1),  # rotated 90 clockwise for display
    7: lambda a: np.swapaxes(a[::-1, ::-1], 0, 1),  # transversed (the anti-diagonal)
    8: lambda a: np.rot90(a, 1),  # rotated 90 counter-clockwise for display
}


@pytest.mark.parametrize("orientation", sorted(EXIF_UPRIGHT))
@pytest.mark.parametrize("kind", ["grey", "rgb", "grey16", "tiff-rgb"])
def test_read_image_applies_the_exif_orientation(
    tmp_path: Path, orientation: int, kind: str
) -> None:
    # Phones and some cameras store the sensor's pixels and say how to turn them; OpenCV's
    # imread and browsers turn them, and so must we: a calibration made from OpenCV-read
    # images refers to the turned frame. Ignoring the tag matched a 90-degree-rotated pair.
    rng = np.random.default_rng(orientation)
    shape = {"grey": (7, 9), "rgb": (7, 9, 3), "grey16": (7, 9), "tiff-rgb": (7, 9, 3)}[kind]
    dtype = np.uint16 if kind == "grey16" else np.uint8
    stored = rng.integers(0, np.iinfo(dtype).max + 1, shape, dtype=dtype)
    path = tmp_path / ("x.tiff" if kind == "tiff-rgb" else "x.png")
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(stored).save(path, exif=exif)
    got = io.read_image(path)
    want = np.ascontiguousarray(EXIF_UPRIGHT[orientation](stored))
    np.testing.assert_array_equal(got, want, strict=True)
    # The size batch checks a job's search range against before reading any pair: the
    # image's sides, in either order (Pillow turns a TIFF's size itself).
    size = io._header_size(path)
    assert size is not None and sorted(size) == sorted(got.shape[:2])


def test_header_size_is_the_size_read_image_gives(tmp_path: Path) -> None:
    """PGM and PPM (8- and 16-bit) by their own header; None for what read_image refuses."""
    rng = np.random.default_rng(5)
    for name, arr in (
        ("g.pgm", rng.integers(0, 256, (5, 11), dtype=np.uint8)),
        ("w.pgm", rng.integers(0, 65536, (6, 3), dtype=np.uint16)),
        ("c.ppm", rng.integers(0, 256, (4, 13, 3), dtype=np.uint8)),
    ):
        kind = b"P6" if arr.ndim == 3 else b"P5"
        top = b"65535" if arr.dtype == np.uint16 else b"255"
        head = kind + b" %d %d " % (arr.shape[1], arr.shape[0]) + top + b"\n"
        (tmp_path / name).write_bytes(head + arr.astype(arr.dtype.newbyteorder(">")).tobytes())
        got = io.read_image(tmp_path / name)
        assert io._header_size(tmp_path / name) == (got.shape[1], got.shape[0]) == arr.shape[1::-1]
    (tmp_path / "junk.png").write_bytes(b"not an image")
    assert io._header_size(tmp_path / "junk.png") is None
    assert io._header_size(tmp_path / "absent.png") is None


@pytest.mark.parametrize("orientation", sorted(EXIF_UPRIGHT))
def test_read_image_turns_as_opencv_imread(tmp_path: Path, orientation: int) -> None:
    cv2 = pytest.importorskip("cv2", reason="the comparison with OpenCV needs opencv-python")
    rng = np.random.default_rng(orientation)
    rgb = rng.integers(0, 256, (7, 9, 3), dtype=np.uint8)
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(rgb).save(tmp_path / "c.png", exif=exif)
    Image.fromarray(rgb[..., 1]).save(tmp_path / "g.png", exif=exif)
    theirs = cv2.imread(str(tmp_path / "c.png"), cv2.IMREAD_COLOR)[..., ::-1]
    np.testing.assert_array_equal(io.read_image(tmp_path / "c.png"), theirs)
    theirs = cv2.imread(str(tmp_path / "g.png"), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(io.read_image(tmp_path / "g.png"), theirs)


def test_read_image_missing_and_corrupt(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"image not found: .*nope\.png"):
        io.read_image(tmp_path / "nope.png")
    # A folder is not "missing": every reader says what it is (same rule for PFM and PNM).
    folder = tmp_path / "folder.png"
    folder.mkdir()
    for reader, what in (
        (io.read_image, "image"),
        (io.read_pfm, "PFM file"),
        (io.read_pnm, "PNM file"),
    ):
        with pytest.raises(
            IsADirectoryError, match=rf"{what} is a folder, not a file: .*folder\.png"
        ):
            reader(folder)
    good = tmp_path / "good.png"
    Image.fromarray(np.zeros((64, 64), np.uint8) + 7).save(good)
    data = good.read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    (tmp_path / "text.png").write_bytes(b"not an image at all")
    for bad in ("cut.png", "text.png"):
        with pytest.raises(ValueError, match=r"cannot decode image .*" + re.escape(bad)):
            io.read_image(tmp_path / bad)


def test_read_image_too_many_pixels_is_a_value_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # A header claiming more than twice Pillow's MAX_IMAGE_PIXELS (179 megapixels; a 48 kB
    # PNG can claim 400) raised DecompressionBombError, which no caller expects: match and
    # eval ended in a traceback. Here the limit is lowered instead of writing such a file.
    from stereodepth import cli

    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)
    Image.fromarray(np.zeros((20, 30), np.uint8)).save(tmp_path / "big.png")
    with pytest.raises(ValueError, match=r"cannot decode image .*big\.png: 600 pixels, more "):
        io.read_image(tmp_path / "big.png")
    big = str(tmp_path / "big.png")
    assert cli.main(["match", big, big, "-o", f"{tmp_path}/", "--no-preview"]) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith("stereodepth match: error: LEFT: cannot decode image")
        and err.count("\n") == 1
    )


def test_read_image_rejects_floating_point_images(tmp_path: Path) -> None:
    # Pillow opens float TIFF and PFM files as mode F; converting them to RGB quantised the
    # samples (0..1 became all black) instead of saying so.
    Image.fromarray(np.linspace(0, 1, 20, dtype=np.float32).reshape(4, 5)).save(tmp_path / "f.tif")
    io.write_pfm(tmp_path / "d.pfm", np.arange(12, dtype=np.float32).reshape(3, 4))
    for name in ("f.tif", "d.pfm"):
        with pytest.raises(ValueError, match=re.escape(name) + r".*floating-point image.*read_pfm"):
            io.read_image(tmp_path / name)


def _png(path: Path, samples: np.ndarray, colour_type: int) -> None:
    """A 16-bit PNG written by hand (the PNG specification; Pillow writes no 16-bit colour)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    h, w = samples.shape[:2]
    rows = samples.astype(">u2").reshape(h, -1).view(np.uint8)
    raw = b"".join(b"\0" + row.tobytes() for row in rows)  # filter type 0 per row
    ihdr = struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )


@pytest.mark.parametrize(
    ("colour_type", "channels", "kind"),
    [(2, 3, "colour"), (6, 4, "colour"), (4, 2, "grey and alpha")],
)
def test_read_image_refuses_16_bit_colour(
    tmp_path: Path, colour_type: int, channels: int, kind: str
) -> None:
    # Pillow reads 16-bit colour (and grey with alpha) as 8 bits, keeping the high byte: a
    # 12-bit colour image (0..4095) became 0..15, almost black, and was matched as such.
    a = np.random.default_rng(1).integers(0, 4096, (5, 6, channels), dtype=np.uint16)
    if channels in (2, 4):
        a[..., -1] = 65535  # opaque
    _png(tmp_path / "c16.png", a, colour_type)
    with pytest.raises(ValueError, match=r"c16\.png: a 16-bit " + kind + r" image .*low byte"):
        io.read_image(tmp_path / "c16.png")
    _png(tmp_path / "g16.png", a[..., 0], 0)  # 16-bit grey is read exactly
    np.testing.assert_array_equal(io.read_image(tmp_path / "g16.png"), a[..., 0], strict=True)


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


@pytest.mark.parametrize("step", ["os.open", "os.fdopen"])
def test_atomic_write_interrupted_just_after_creating_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, step: str
) -> None:
    # A Ctrl-C or SIGTERM (a KeyboardInterrupt, raised between any two steps) that came just
    # after the temporary file was created, before the block that removes it began, left it
    # in the folder for good: seen once in 250 SIGTERMs to `stereodepth match`.
    target = tmp_path / "out.bin"
    target.write_bytes(b"first")
    name = step.split(".")[1]
    real = getattr(os, name)

    def then_interrupted(*args: Any, **kwargs: Any) -> Any:
        result = real(*args, **kwargs)
        if name == "open" and ".stereodepth-" not in str(args[0]):
            return result
        if name == "fdopen":
            result.close()
        raise KeyboardInterrupt

    monkeypatch.setattr(os, name, then_interrupted)
    with pytest.raises(KeyboardInterrupt), io.atomic_write(target) as f:
        f.write(b"second")
    monkeypatch.undo()
    assert names(tmp_path) == ["out.bin"]
    assert target.read_bytes() == b"first"


def test_atomic_writers_name_a_folder_in_the_way(tmp_path: Path) -> None:
    # The rename's IsADirectoryError named the temporary file ('.d.png.stereodepth-....tmp'
    # -> 'd.png'); now every atomic writer names the user's path, before writing anything.
    import importlib.util

    from stereodepth import StereoRig, save_colorized
    from stereodepth.plotting import save_charts

    folder = tmp_path / "d.png"
    folder.mkdir()
    writers = [
        lambda: io.write_pfm(folder, np.ones((2, 2), np.float32)),
        lambda: io.write_npy(folder, np.ones(2)),
        lambda: io.write_png16(folder, np.ones((2, 2), np.uint16)),
    ]
    if importlib.util.find_spec("matplotlib") is not None:  # the plot extra
        writers.append(lambda: save_colorized(folder, np.ones((3, 3))))
        rig = StereoRig.from_pixels(baseline_mm=100, focal_px=700)
        writers.append(lambda: save_charts(rig, folder))
    for write in writers:
        with pytest.raises(
            IsADirectoryError, match=r"cannot write a file over a folder: .*d\.png'$"
        ):
            write()
        assert names(tmp_path) == ["d.png"] and not list(folder.iterdir())


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


@pytest.mark.skipif(not hasattr(os, "fchmod"), reason="POSIX permissions")
def test_atomic_writers_keep_the_permissions_of_a_file_they_replace(tmp_path: Path) -> None:
    disparity = np.ones((4, 5), np.float32)
    writers = {
        "d.npy": lambda p: io.write_npy(p, disparity),
        "d.pfm": lambda p: io.write_pfm(p, disparity),
        "d.png": lambda p: io.write_png16(p, np.ones((4, 5), np.uint16)),
    }
    for name, write in writers.items():
        target = tmp_path / name
        target.write_bytes(b"old")
        target.chmod(0o640)  # a user's choice (a group may read, others not)
        write(target)
        assert target.stat().st_mode & 0o777 == 0o640, name
        assert target.read_bytes() != b"old"


@pytest.mark.skipif(os.name != "posix", reason="POSIX permissions")
def test_atomic_writers_do_not_replace_a_read_only_file(tmp_path: Path) -> None:
    """open() refuses to overwrite a file without write permission, but renaming over it
    needs only the folder's: a result or an input the user had made read-only (chmod a-w)
    was replaced by every writer without a word. Refused naming the path, the file kept."""
    import importlib.util

    from stereodepth import save_colorized

    disparity = np.ones((4, 5), np.float32)
    writers = {
        "d.npy": lambda p: io.write_npy(p, disparity),
        "d.pfm": lambda p: io.write_pfm(p, disparity),
        "d.png": lambda p: io.write_png16(p, np.ones((4, 5), np.uint16)),
        "k.png": lambda p: io.write_disparity_png16(p, disparity),
        "d.ply": lambda p: write_ply(p, np.ones((3, 3))),
    }
    if importlib.util.find_spec("matplotlib") is not None:  # the plot extra
        writers["c.png"] = lambda p: save_colorized(p, disparity)
    for name, write in writers.items():
        target = tmp_path / name
        target.write_bytes(b"keep me")
        target.chmod(0o444)
        with pytest.raises(PermissionError, match="the file is read-only") as info:
            write(target)
        assert info.value.filename == str(target), name
        assert target.read_bytes() == b"keep me", name
        target.chmod(0o644)  # writable again: replaced as before
        write(target)
        assert target.read_bytes() != b"keep me", name
    assert names(tmp_path) == sorted(writers)  # no temporary file left


@pytest.mark.skipif(os.name != "posix", reason="symbolic links")
def test_atomic_writers_write_through_a_link(tmp_path: Path) -> None:
    """A path that is a symbolic link (out/d.npy -> a shared disk's file) was replaced by a
    new file: the link was gone and the file it named kept the old data, where open(),
    numpy.save and cv2.imwrite write into that file. Now the file the link names gets the
    new data (its permissions kept, no temporary file left) and the link stays."""
    disparity = np.arange(20, dtype=np.float32).reshape(4, 5)
    writers = {
        "d.npy": (lambda p: io.write_npy(p, disparity), lambda p: np.load(p)),
        "d.pfm": (lambda p: io.write_pfm(p, disparity), io.read_pfm),
        "d.png": (lambda p: io.write_png16(p, disparity.astype(np.uint16)), io.read_image),
        "d.ply": (lambda p: write_ply(p, np.ones((3, 3))), lambda p: p.read_bytes()[:3]),
    }
    shared, out = tmp_path / "shared", tmp_path / "out"
    shared.mkdir()
    out.mkdir()
    for name, (write, read) in writers.items():
        target = shared / name
        target.write_bytes(b"old")
        target.chmod(0o640)
        link = out / name
        link.symlink_to(Path("..") / "shared" / name)
        write(link)
        assert link.is_symlink(), name
        assert target.read_bytes() != b"old", name
        np.testing.assert_array_equal(read(link), read(target))
        assert target.stat().st_mode & 0o777 == 0o640, name
    assert names(shared) == sorted(writers) and names(out) == sorted(writers)
    # A link to nothing yet: the file it names is made.
    (out / "new.npy").symlink_to(shared / "new.npy")
    io.write_npy(out / "new.npy", disparity)
    assert (out / "new.npy").is_symlink()
    np.testing.assert_array_equal(np.load(shared / "new.npy"), disparity)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
def test_atomic_writers_write_into_a_pipe_not_over_it(tmp_path: Path) -> None:
    """A path that is a device or a pipe was replaced by a regular file (the temporary file
    renamed over it): a FIFO's reader never got the data, and as root write_pfm("/dev/null",
    ...) made /dev/null a regular file. Such a path is written to as open() writes it."""
    import stat
    import threading

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    disparity = np.arange(12, dtype=np.float32).reshape(3, 4)
    got: list[bytes] = []

    def read() -> None:
        with open(fifo, "rb") as f:  # blocks until a writer opens the pipe
            got.append(f.read())

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    io.write_pfm(fifo, disparity)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)  # still the pipe, not a file
    reader.join(timeout=30)
    assert not reader.is_alive()
    io.write_pfm(tmp_path / "ref.pfm", disparity)
    assert got == [(tmp_path / "ref.pfm").read_bytes()]
    assert names(tmp_path) == ["pipe", "ref.pfm"]  # no temporary file left


def test_atomic_writers_take_names_up_to_the_file_systems_limit(tmp_path: Path) -> None:
    # The temporary name adds 31 bytes to the target's: a name of 225 to 255 bytes (legal,
    # say a batch stem from deep folders) failed with "File name too long" naming the
    # temporary file. Every writer goes through atomic_write.
    disparity = np.ones((4, 5), np.float32)
    writers = {
        "npy": lambda p: io.write_npy(p, disparity),
        "pfm": lambda p: io.write_pfm(p, disparity),
        "png": lambda p: io.write_png16(p, np.ones((4, 5), np.uint16)),
        "ply": lambda p: write_ply(p, np.ones((2, 3), np.float32)),
    }
    for ext, write in writers.items():
        for stem in ("d" * (254 - len(ext)), "\u00e9" * ((254 - len(ext)) // 2)):
            target = tmp_path / f"{stem}.{ext}"
            assert len(target.name.encode()) >= 253
            write(target)
            assert target.stat().st_size > 0
    assert not [n for n in names(tmp_path) if n.endswith(".tmp")]
    assert len(names(tmp_path)) == 2 * len(writers)


def test_atomic_writers_name_the_users_path_when_the_folder_takes_no_file(tmp_path: Path) -> None:
    # The error of creating the temporary file named it (".d.npy.stereodepth-<hex>.tmp"), a
    # path the user never gave: `match -o /proc/` said so.
    disparity = np.ones((4, 5), np.float32)
    writers = {
        "d.npy": lambda p: io.write_npy(p, disparity),
        "d.pfm": lambda p: io.write_pfm(p, disparity),
        "d.png": lambda p: io.write_png16(p, np.ones((4, 5), np.uint16)),
    }
    for name, write in writers.items():
        target = tmp_path / "missing" / name
        with pytest.raises(FileNotFoundError) as info:
            write(target)
        assert info.value.filename == str(target)
        assert f"cannot write {name}" in str(info.value) and ".tmp" not in str(info.value)


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
    with pytest.raises(TypeError, match=r"compress_level must be an integer, got True"):
        io.write_png16(tmp_path / "x.png", a, compress_level=True)
    with pytest.raises(TypeError, match=r"compress_level must be an integer, got np\.True_"):
        io.write_png16(tmp_path / "x.png", a, compress_level=np.True_)  # type: ignore[arg-type]
    assert names(tmp_path) == ["0.png", "1.png", "9.png"]
    # numpy integers are integers (every other integer parameter of the package takes them).
    io.write_png16(tmp_path / "np.png", a, compress_level=np.int64(9))  # type: ignore[arg-type]
    assert (tmp_path / "np.png").read_bytes() == (tmp_path / "9.png").read_bytes()


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
            [np.nan, -3.0, np.inf, 65535 / 256],
            [1 / 1024, 1 / 256, 100.00195, 2.5],
        ],
        np.float32,
    )
    io.write_disparity_png16(tmp_path / "d.png", d)
    raw = io.read_image(tmp_path / "d.png")
    assert raw.dtype == np.uint16
    # float32 100.00195 is exactly 100 + 1/512: 25600.5, rounded half up as KITTI's devkit
    want = [[0, 256, 2688, 65533], [0, 0, 0, 65535], [0, 1, 25601, 640]]
    assert raw.tolist() == want
    ok = raw > 0
    np.testing.assert_allclose(raw[ok] / 256, d[ok], atol=1 / 512)
    # Beyond 255.996 px the format has no value: refused, nothing written (it was capped).
    d[1, 3] = 300.0
    with pytest.raises(ValueError, match=r"disparity up to 300 px does not fit a 16-bit"):
        io.write_disparity_png16(tmp_path / "e.png", d)
    assert not (tmp_path / "e.png").exists()


def test_read_disparity_png16_is_kitti_devkit_decoding(tmp_path: Path) -> None:
    """KITTI's devkit reads d = png / 256 with 0 as no value. The writer's docstring said to
    read its files back with read_image(path) / 256, which gives every hole disparity 0 (a
    valid disparity, a point at infinity: evaluate scored them as estimates, depth as
    infinitely far). read_disparity_png16 decodes as the devkit, checked against an
    independent decoding (OpenCV's where installed, else Pillow's)."""
    raw = np.array([[0, 1, 256, 65535], [2688, 0, 65533, 640]], np.uint16)
    Image.fromarray(raw).save(tmp_path / "k.png")
    try:
        import cv2

        decoded = cv2.imread(str(tmp_path / "k.png"), cv2.IMREAD_UNCHANGED)
    except ImportError:
        decoded = np.asarray(Image.open(tmp_path / "k.png"))
    assert decoded.dtype == np.uint16
    want = np.where(decoded > 0, decoded.astype(np.float64) / 256.0, np.nan)
    got = io.read_disparity_png16(tmp_path / "k.png")
    assert got.dtype == np.float32 and got.shape == (2, 4)
    np.testing.assert_array_equal(got.astype(np.float64), want)
    # The writer's files read back to the disparity rounded to 1/256 px, holes NaN.
    d = np.array([[np.nan, 1.0, 10.5, -2.0], [0.0, 255.99, 3.3, np.inf]], np.float32)
    io.write_disparity_png16(tmp_path / "d.png", d)
    back = io.read_disparity_png16(tmp_path / "d.png")
    hole = ~(np.isfinite(d) & (d > 0))
    assert (np.isnan(back) == hole).all()
    np.testing.assert_array_equal(back[~hole], np.rint(d[~hole] * 256.0) / 256.0)


def test_read_disparity_png16_ignores_an_exif_orientation(tmp_path: Path) -> None:
    """A disparity map is data, read as stored by KITTI's devkit and cv2.IMREAD_UNCHANGED;
    read_image turns a photo by its EXIF tag, and a disparity PNG carrying one (written by a
    tool that copied the photo's metadata) came back turned, off its image's pixels."""
    raw = np.arange(1, 13, dtype=np.uint16).reshape(3, 4) * 256
    exif = Image.Exif()
    exif[0x0112] = 6  # turned 90 degrees for display
    Image.fromarray(raw).save(tmp_path / "d.png", exif=exif)
    assert io.read_image(tmp_path / "d.png").shape == (4, 3)  # a photo is turned
    got = io.read_disparity_png16(tmp_path / "d.png")
    np.testing.assert_array_equal(got, raw.astype(np.float32) / 256)
    try:
        import cv2
    except ImportError:
        return
    theirs = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(got * 256, theirs.astype(np.float32))


@pytest.mark.parametrize(
    ("image", "kind"),
    [
        (np.full((3, 4), 7, np.uint8), r"an 8-bit grey image of shape \(3, 4\)"),
        (np.full((3, 4, 3), 7, np.uint8), r"a colour image of shape \(3, 4, 3\)"),
    ],
)
def test_read_disparity_png16_refuses_8_bit_and_colour(
    tmp_path: Path, image: np.ndarray, kind: str
) -> None:
    # An 8-bit PNG (a preview, or a map saved by a tool that cut it to 8 bits) is not KITTI's
    # d * 256: 7 would read as 0.027 px.
    Image.fromarray(image).save(tmp_path / "p.png")
    with pytest.raises(
        ValueError, match=r"p\.png: a KITTI disparity PNG is a 16-bit grey image .*" + kind
    ):
        io.read_disparity_png16(tmp_path / "p.png")
    with pytest.raises(FileNotFoundError):
        io.read_disparity_png16(tmp_path / "missing.png")


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


def pfm_bytes(a: np.ndarray, header: bytes) -> bytes:
    """A PFM file with the given header and ``a``'s rows bottom to top, little-endian."""
    return header + np.ascontiguousarray(a[::-1], dtype="<f4").tobytes()


def float_starting_with(prefix: bytes) -> np.float32:
    """A float32 whose little-endian bytes start with ``prefix``."""
    return np.frombuffer(prefix + b"\x01\x02\x20\x3f"[len(prefix) :], "<f4")[0]


@pytest.mark.parametrize("prefix", [b"\r", b"\n", b"\r\n", b"\n\r", b"\n\n", b" \t"])
@pytest.mark.parametrize("shape", [(1, 1), (2, 3), (2, 2, 3)])
def test_pfm_round_trip_data_looking_like_line_ends(
    tmp_path: Path, prefix: bytes, shape: tuple[int, ...]
) -> None:
    """The first data bytes 0x0D / 0x0A (the bottom row's first value on disk) are data."""
    a = np.full(shape, 0.5, np.float32)
    a[-1].flat[0] = float_starting_with(prefix)
    io.write_pfm(tmp_path / "a.pfm", a)
    header = f"{'Pf' if a.ndim == 2 else 'PF'}\n{shape[1]} {shape[0]}\n-1.0\n".encode()
    assert (tmp_path / "a.pfm").read_bytes().startswith(header + prefix)
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "a.pfm"), a, strict=True)


@pytest.mark.parametrize(
    "header",
    [
        b"Pf\r\n3 2\r\n-1\r\n",  # Windows line ends
        b"Pf\r\n3 2\r\n-1.000000\r\n",
        b"Pf \n3 2 \n-1 \n",  # trailing spaces
        b"Pf\t\r\n3\t2\t\r\n-1\t \r\n",
        b"Pf 3 2 -1\n",  # one line
        b"Pf\n\n3\n2\n-1\n",  # blank lines and a field a line
    ],
)
@pytest.mark.parametrize("prefix", [b"\n", b"\r", b"\r\n", b"1"])
def test_pfm_header_layouts(tmp_path: Path, header: bytes, prefix: bytes) -> None:
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    a[1, 0] = float_starting_with(prefix)  # the first value on disk
    (tmp_path / "a.pfm").write_bytes(pfm_bytes(a, header))
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "a.pfm"), a, strict=True)


def test_pfm_crlf_header_was_read_one_byte_off(tmp_path: Path) -> None:
    """Issue 10 item 2: a CR LF header used to shift the data by one byte, with no error."""
    a = np.array([[1.5, -2.25], [3.0, 1e-3]], np.float32)
    (tmp_path / "w.pfm").write_bytes(pfm_bytes(a, b"Pf\r\n2 2\r\n-1.0\r\n"))
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "w.pfm"), a, strict=True)


A23 = np.arange(6, dtype=np.float32).reshape(2, 3)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", r"not a PFM file: it must start with 'PF' or 'Pf', got b''"),
        (b"P6\n3 2\n255\n" + bytes(18), r"not a PFM file: .*got b'P6\\n3"),
        (b"pf\n3 2\n-1\n" + bytes(24), "not a PFM file"),
        (b"Pfx\n3 2\n-1\n" + bytes(24), "not a PFM file"),
        (b"Pf\n3 2\n", r"incomplete PFM header: expected 3 fields after the magic, got 2"),
        (b"Pf\n# by a tool\n3 2\n-1\n" + bytes(24), r"PFM headers have no comments, got a '#'"),
        (b"Pf\n3 2\n# x\n-1\n" + bytes(24), "PFM headers have no comments"),
        (b"Pf\nthree 2\n-1\n" + bytes(24), r"PFM width must be a whole number > 0, got 'three'"),
        (b"Pf\n3 -2\n-1\n" + bytes(24), r"PFM height must be a whole number > 0, got '-2'"),
        (b"Pf\n0 2\n-1\n", r"PFM width must be a whole number > 0, got '0'"),
        (b"Pf\n3 0\n-1\n", r"PFM height must be a whole number > 0, got '0'"),
        (b"Pf\n3.0 2\n-1\n" + bytes(24), r"PFM width must be a whole number > 0, got '3.0'"),
        # int() refuses over 4300 digits, in a message naming no file
        (b"Pf\n" + b"9" * 5000 + b" 2\n-1\n", r"PFM width must be a whole number > 0, got 5000 d"),
        (b"Pf\n3 2\n0\n" + bytes(24), r"bad PFM scale '0': it must be finite and not 0"),
        (b"Pf\n3 2\n-0.0\n" + bytes(24), r"bad PFM scale '-0.0'"),
        (b"Pf\n3 2\n-1e999\n" + bytes(24), r"bad PFM scale '-1e999'"),
        (b"Pf\n3 2\nnan\n" + bytes(24), r"PFM scale must be a number, got 'nan'"),
        (b"Pf\n3 2\n-1x\n" + bytes(24), r"PFM scale must be a number, got '-1x'"),
        (b"PF\n3 2\n-1\n" + bytes(40), r"truncated 3x2x3 PFM: needs 72 bytes of data, got 40"),
        (b"Pf\n3 2\n-1\n", r"truncated 3x2x1 PFM: needs 24 bytes of data, got 0"),
        (b"Pf\n3 2\n-1", r"truncated 3x2x1 PFM: needs 24 bytes of data, got 0"),
        (b"Pf\n3 2\n-1\n" + bytes(23), r"truncated 3x2x1 PFM: needs 24 bytes of data, got 23"),
        # a CR LF header one byte short must not be read as a header ending in a lone CR
        (
            pfm_bytes(A23, b"Pf\r\n3 2\r\n-1\r\n")[:-1],
            r"truncated 3x2x1 PFM: needs 24 bytes of data, got 23",
        ),
        (
            pfm_bytes(A23, b"Pf\n3 2\n-1 \n")[:-1],
            r"truncated 3x2x1 PFM: needs 24 bytes of data, got 23",
        ),
        (
            b"Pf\n3 2\n-1\r" + bytes(24),
            r"header must end with one line break \(LF or CR LF\), got b'\\r\\x00",
        ),
        (
            b"Pf 3 2 -1 " + bytes(24),
            r"header must end with one line break \(LF or CR LF\), got b' \\x00",
        ),
        (b"Pf\n3 2\n-1\n" + bytes(25), r"3x2x1 PFM has 1 bytes more than its header and 24 bytes"),
        (b"Pf\r\n3 2\r\n-1\r\n" + bytes(30), r"has 6 bytes more than its header and 24 bytes"),
        (b"Pf\n3 2\n-1\n\n" + bytes(24), r"3x2x1 PFM has 1 bytes more than its header and 24"),
    ],
)
def test_read_pfm_rejects(tmp_path: Path, content: bytes, message: str) -> None:
    (tmp_path / "bad.pfm").write_bytes(content)
    with pytest.raises(ValueError, match=r"^\S*bad\.pfm: (.* )?" + message):
        io.read_pfm(tmp_path / "bad.pfm")


def test_read_pfm_missing(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"PFM file not found: .*nope\.pfm"):
        io.read_pfm(tmp_path / "nope.pfm")


def test_pfm_writer_is_read_by_opencv(tmp_path: Path) -> None:
    """Byte compatibility of write_pfm with another reader (OpenCV's), where installed."""
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    a = np.random.default_rng(3).normal(size=(5, 7)).astype(np.float32)
    a[4, 0] = float_starting_with(b"\r\n")
    io.write_pfm(tmp_path / "a.pfm", a)
    np.testing.assert_array_equal(
        cv2.imread(str(tmp_path / "a.pfm"), cv2.IMREAD_UNCHANGED), a, strict=True
    )


# --- PBM / PGM / PPM --------------------------------------------------------------------------
def pgm(header: bytes, a: np.ndarray) -> bytes:
    return (
        header + np.ascontiguousarray(a).astype(">u2" if a.dtype == np.uint16 else "u1").tobytes()
    )


@pytest.mark.parametrize(
    ("header", "a"),
    [
        (b"P5\n2 1\n255\n", np.array([[10, 13]], np.uint8)),
        (b"P5\r\n2 1\r\n255\r\n", np.array([[10, 13]], np.uint8)),  # Pillow and OpenCV: 10, 10
        (b"P5\r\n2 1\r\n255\r\n", np.array([[13, 10]], np.uint8)),
        (b"P5 \n# made by hand\r\n# two comments\n2 1 \n255 \n", np.array([[10, 10]], np.uint8)),
        (b"P5 2#width\n1 255\n", np.array([[10, 13]], np.uint8)),
        (b"P5\n3 2\n4095\n", np.array([[0, 4095, 2560], [13, 10, 3338]], np.uint16)),  # 12-bit
        (b"P5\r\n3 1\r\n65535\r\n", np.array([[3338, 65535, 0]], np.uint16)),
        (b"P5\n2 1\n15\n", np.array([[10, 15]], np.uint8)),  # not stretched to 255
        (b"P6\n2 1\n255\n", np.array([[[10, 13, 10], [1, 2, 3]]], np.uint8)),
        (b"P6\r\n1 1\r\n4095\r\n", np.array([[[3338, 4095, 0]]], np.uint16)),
    ],
)
def test_pnm_binary(tmp_path: Path, header: bytes, a: np.ndarray) -> None:
    (tmp_path / "a.pnm").write_bytes(pgm(header, a))
    np.testing.assert_array_equal(io.read_pnm(tmp_path / "a.pnm"), a, strict=True)
    np.testing.assert_array_equal(io.read_image(tmp_path / "a.pnm"), a, strict=True)


def test_pnm_agrees_with_opencv_on_lf_headers(tmp_path: Path) -> None:
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed")
    rng = np.random.default_rng(4)
    for header, a in [
        (b"P5\n7 3\n255\n", rng.integers(0, 256, (3, 7), dtype=np.uint8)),
        (b"P5\n7 3\n4095\n", rng.integers(0, 4096, (3, 7), dtype=np.uint16)),
        (b"P6\n5 2\n255\n", rng.integers(0, 256, (2, 5, 3), dtype=np.uint8)),
    ]:
        a.flat[0] = 10
        (tmp_path / "a.pnm").write_bytes(pgm(header, a))
        theirs = cv2.imread(str(tmp_path / "a.pnm"), cv2.IMREAD_UNCHANGED)
        if a.ndim == 3:
            theirs = theirs[..., ::-1]  # OpenCV gives BGR
        np.testing.assert_array_equal(io.read_pnm(tmp_path / "a.pnm"), theirs, strict=True)


def test_pnm_plain_and_bitmaps(tmp_path: Path) -> None:
    cases = [
        (
            b"P2\r\n# plain\r\n3 2\r\n300\r\n0 1 2\r\n300 4 5\r\n",
            [[0, 1, 2], [300, 4, 5]],
            np.uint16,
        ),
        (b"P2 2 1 9 9 0", [[9, 0]], np.uint8),
        (b"P3\n1 2\n255\n1 2 3\n4 5 6\n", [[[1, 2, 3]], [[4, 5, 6]]], np.uint8),
        (b"P1\n# a bitmap\n3 2\n101\r\n0 1 0\n", [[0, 255, 0], [255, 0, 255]], np.uint8),
        (b"P4\n3 2\n\xa0\x40", [[0, 255, 0], [255, 0, 255]], np.uint8),
        (b"P4\r\n9 1\r\n\x0a\x80", [[255] * 4 + [0, 255, 0, 255, 0]], np.uint8),
    ]
    for content, want, dtype in cases:
        (tmp_path / "a.pnm").write_bytes(content)
        got = io.read_pnm(tmp_path / "a.pnm")
        np.testing.assert_array_equal(got, np.array(want, dtype), strict=True)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"P7\nWIDTH 1\n", r"not a PBM/PGM/PPM file: it must start with P1 to P6, got b'P7"),
        (b"P5x 1 1 255\n\x00", "not a PBM/PGM/PPM file"),
        (b"P5\n2 1\n", r"incomplete PGM header: expected 3 fields after the magic, got 2"),
        (b"P5\n2 1 # no maxval\n", "incomplete PGM header"),
        (b"P5\ntwo 1\n255\n\x00\x00", r"PGM width must be a whole number > 0, got 'two'"),
        (b"P5\n2 0\n255\n", r"PGM height must be a whole number > 0, got '0'"),
        (b"P5\n2 1\n0\n\x00\x00", r"PGM maxval must be a whole number > 0, got '0'"),
        (b"P5\n2 1\n-255\n\x00\x00", r"PGM maxval must be a whole number > 0, got '-255'"),
        (b"P5\n2 1\n65536\n" + bytes(4), r"PGM maxval must be at most 65535, got 65536"),
        (b"P5\n2 1\n255\n\x00", r"truncated 2x1 PGM with maxval 255: needs 2 bytes of data, got 1"),
        (b"P6\n2 1\n1000\n" + bytes(11), r"truncated 2x1 PPM with maxval 1000: needs 12 bytes"),
        # a CR LF header one byte short, and a header ending with a lone space (netpbm allows
        # it, but then a body one byte short reads shifted): refused
        (
            b"P5\r\n2 1\r\n255\r\n\x0a",
            r"truncated 2x1 PGM with maxval 255: needs 2 bytes of data, got 1",
        ),
        (
            b"P5 2 1 255 \x0a\x0d",
            r"truncated 2x1 PGM with maxval 255: needs 2 bytes of data, got 1",
        ),
        (
            b"P5 2 1 255 \x01\x0d",
            r"the header must end with one line break \(LF or CR LF\), got b' \\x01",
        ),
        (b"P5\n2 1\n255\r\x01\x0d", r"the header must end with one line break .*got b'\\r\\x01"),
        (b"P5\n2 1\n255\n\x00\x00\x00", r"2x1 PGM with maxval 255 has 1 bytes more than its"),
        (b"P5\n2 1\n15\n\x10\x00", r"2x1 PGM with maxval 15 has a sample 16 above the maxval"),
        (b"P5\n1 1\n4095\n\x10\x00", r"has a sample 4096 above the maxval"),
        (b"P4\n9 2\n\x00\x00\x00", r"truncated 9x2 PBM: needs 4 bytes of data, got 3"),
        (b"P2\n2 2\n255\n1 2 3\n", r"2x2 PGM with maxval 255 needs 4 samples, got 3"),
        (b"P2\n2 1\n255\n1 2 3\n", r"needs 2 samples, got 3"),
        (b"P2\n2 1\n255\n1 # two\n", r"PGM samples must be whole numbers, got b'#'"),
        (b"P2\n2 1\n255\n1 -2\n", r"PGM samples must be whole numbers, got b'-2'"),
        (b"P2\n2 1\n255\n1 256\n", r"has a sample 256 above the maxval"),
        (b"P2\n1 1\n255\n" + b"9" * 40, r"has a sample above the maxval"),
        (b"P2\n1 1\n255#c\n1", r"PGM header must end with whitespace, got b'#c"),
        (b"P1\n2 1\n0 2\n", r"PBM samples must be 0 or 1, got b'2'"),
        (b"P1\n2 1\n0\n", r"2x1 PBM needs 2 samples, got 1"),
        (
            b"P5\n2 1\n" + b"1" * 4400 + b"\n\x00\x00",
            r"PGM maxval must be a whole number > 0, got 4400",
        ),
    ],
)
def test_read_pnm_rejects(tmp_path: Path, content: bytes, message: str) -> None:
    (tmp_path / "bad.pgm").write_bytes(content)
    with pytest.raises(ValueError, match=r"^\S*bad\.pgm: (.* )?" + message):
        io.read_pnm(tmp_path / "bad.pgm")
    if content.startswith((b"P1", b"P2", b"P3", b"P4", b"P5", b"P6")):
        with pytest.raises(ValueError, match=r"^\S*bad\.pgm: (.* )?" + message):
            io.read_image(tmp_path / "bad.pgm")


def test_read_pnm_missing(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"PNM file not found: .*nope\.pgm"):
        io.read_pnm(tmp_path / "nope.pgm")


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
        # A str reached numpy's isfinite (a TypeError naming no parameter); a bool was
        # written as the scale 1.0.
        (
            np.zeros((2, 2), np.float32),
            {"scale": "1"},
            TypeError,
            "scale must be a real number, got str '1'",
        ),
        (
            np.zeros((2, 2), np.float32),
            {"scale": True},
            TypeError,
            "scale must be a real number, got bool True",
        ),
        (
            np.zeros((2, 2), np.float32),
            {"scale": float("nan")},
            ValueError,
            "scale must be a finite number > 0, got nan",
        ),
    ],
)
def test_write_pfm_rejects(
    tmp_path: Path, array: np.ndarray, kwargs: dict[str, Any], exc: type, message: str
) -> None:
    with pytest.raises(exc, match=message):
        io.write_pfm(tmp_path / "x.pfm", array, **kwargs)
    assert names(tmp_path) == []


def test_write_pfm_numpy_scale(tmp_path: Path) -> None:
    # A scale from numpy (np.float32 from a header array) is a real number like any other.
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    io.write_pfm(tmp_path / "x.pfm", a, scale=np.float32(0.5))
    assert (tmp_path / "x.pfm").read_bytes().startswith(b"Pf\n3 2\n-0.5\n")
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "x.pfm"), a, strict=True)


# --- exact or refused, for any data: property tests --------------------------------------------
LINE_ENDS = st.sampled_from(["\n", "\r\n", " \n", "\t\r\n"])


@settings(max_examples=150, deadline=None)
@given(
    width=st.integers(1, 9),
    height=st.integers(1, 5),
    colour=st.booleans(),
    ends=st.lists(LINE_ENDS, min_size=3, max_size=3),
    little=st.booleans(),
    data=st.data(),
)
def test_pfm_any_bytes_any_layout(
    width: int, height: int, colour: bool, ends: list[str], little: bool, data: st.DataObject
) -> None:
    """Every body, whatever its bytes (0x0A, 0x0D, NaN payloads), under every header layout,
    reads back bit for bit; one byte less or more is refused."""
    channels = 3 if colour else 1
    body = data.draw(
        st.binary(min_size=width * height * channels * 4, max_size=width * height * channels * 4)
    )
    header = (
        f"{'PF' if colour else 'Pf'}{ends[0]}{width} {height}{ends[1]}"
        f"{'-1.0' if little else '1.0'}{ends[2]}"
    ).encode()
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "a.pfm"
        path.write_bytes(header + body)
        got = io.read_pfm(path)
        shape = (height, width, 3) if colour else (height, width)
        want = np.frombuffer(body, "<f4" if little else ">f4").reshape(shape)[::-1]
        assert got.shape == shape
        np.testing.assert_array_equal(got.view(np.uint32), want.astype(np.float32).view(np.uint32))
        for cut in (header + body[:-1], header + body + body[:1]):
            path.write_bytes(cut)
            with pytest.raises(ValueError, match=r"a\.pfm: "):
                io.read_pfm(path)


@settings(max_examples=150, deadline=None)
@given(
    width=st.integers(1, 9),
    height=st.integers(1, 5),
    kind=st.sampled_from(["P5", "P6"]),
    maxval=st.sampled_from([1, 15, 255, 256, 4095, 65535]),
    ends=st.lists(LINE_ENDS, min_size=3, max_size=3),
    comment=st.sampled_from(["", "# a comment\n", "# crlf comment\r\n"]),
    data=st.data(),
)
def test_pnm_any_samples_any_layout(
    width: int,
    height: int,
    kind: str,
    maxval: int,
    ends: list[str],
    comment: str,
    data: st.DataObject,
) -> None:
    samples = 3 if kind == "P6" else 1
    shape = (height, width, 3) if samples == 3 else (height, width)
    dtype = np.uint8 if maxval < 256 else np.uint16
    values = np.array(
        data.draw(
            st.lists(
                st.integers(0, maxval),
                min_size=width * height * samples,
                max_size=width * height * samples,
            )
        ),
        dtype=dtype,
    ).reshape(shape)
    header = f"{kind}{ends[0]}{comment}{width} {height}{ends[1]}{maxval}{ends[2]}".encode()
    body = values.astype(">u2" if dtype == np.uint16 else "u1").tobytes()
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "a.pnm"
        path.write_bytes(header + body)
        np.testing.assert_array_equal(io.read_image(path), values, strict=True)
        for cut in (header + body[:-1], header + body + body[:1]):
            path.write_bytes(cut)
            with pytest.raises(ValueError, match=r"a\.pnm: "):
                io.read_pnm(path)


def test_require_file_names_a_device_as_one() -> None:
    """/dev/null exists: "not found" misled; a device or pipe is refused as what it is."""
    from stereodepth.io import require_file

    if not os.path.exists(os.devnull) or os.path.isfile(os.devnull):
        pytest.skip("no device file to try")
    with pytest.raises(FileNotFoundError, match="image is not a regular file .*: " + os.devnull):
        require_file(os.devnull, "image")


def test_readers_and_writers_name_a_path_that_is_not_one(tmp_path: Path) -> None:
    # pathlib's "expected str, bytes or os.PathLike object, not int" named no parameter;
    # write_ply, save_colorized and save_charts already said "path must be a str or ...".
    from stereodepth import calib

    a = np.zeros((2, 2), np.float32)
    calls = {
        "read_image": io.read_image,
        "read_pfm": io.read_pfm,
        "read_pnm": io.read_pnm,
        "write_npy": lambda p: io.write_npy(p, a),
        "write_pfm": lambda p: io.write_pfm(p, a),
        "write_png16": lambda p: io.write_png16(p, a.astype(np.uint16)),
        "write_disparity_png16": lambda p: io.write_disparity_png16(p, a),
        "read_stereo_calibration": calib.read_stereo_calibration,
        "read_middlebury_calib": calib.read_middlebury_calib,
        "read_kitti_calib": calib.read_kitti_calib,
        "read_calibration": calib.read_calibration,
    }
    for call in calls.values():
        for bad in (123, None, b"/tmp/x.png"):
            with pytest.raises(TypeError, match=r"^path must be a str or os\.PathLike, got "):
                call(bad)
    with pytest.raises(TypeError, match=r"^directory must be a str or os\.PathLike, got int"):
        io.remove_temp_files(5)  # type: ignore[arg-type]
    (tmp_path / "calib.txt").write_text("cam0=[1 0 0; 0 1 0; 0 0 1]\nbaseline=1\n")
    with pytest.raises(TypeError, match=r"^second_path must be a str or os\.PathLike, got int"):
        calib.read_stereo_calibration(tmp_path / "calib.txt", second_path=5)


def test_empty_path_is_refused_not_the_current_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """pathlib reads "" as "." (the current folder): read_image("") said "image is a folder,
    not a file: .", and a writer's error named '.' too. Every reader and writer of the package
    refuses "" by its parameter's name, before touching anything."""
    import stereodepth
    from stereodepth import calib
    from stereodepth.plotting import save_charts

    monkeypatch.chdir(tmp_path)
    a = np.zeros((2, 3), np.float32)
    rig = stereodepth.StereoRig.from_pixels(baseline_mm=100.0, focal_px=700.0)
    calls = {
        "read_image": lambda: io.read_image(""),
        "read_pfm": lambda: io.read_pfm(""),
        "read_pnm": lambda: io.read_pnm(""),
        "write_pfm": lambda: io.write_pfm("", a),
        "write_npy": lambda: io.write_npy("", a),
        "write_png16": lambda: io.write_png16("", a.astype(np.uint16)),
        "write_disparity_png16": lambda: io.write_disparity_png16("", a),
        "atomic_write": lambda: io.atomic_write("").__enter__(),
        "write_ply": lambda: write_ply("", np.zeros((2, 3))),
        "save_charts": lambda: save_charts(rig, ""),
        "read_stereo_calibration": lambda: calib.read_stereo_calibration(""),
        "from_middlebury_calib": lambda: stereodepth.StereoRig.from_middlebury_calib(""),
        "StereoRectifier.from_file": lambda: stereodepth.StereoRectifier.from_file(""),
    }
    for name, call in calls.items():
        with pytest.raises(ValueError, match=r"^path must not be empty, got ''$"):
            call()
        assert list(tmp_path.iterdir()) == [], name
    with pytest.raises(ValueError, match=r"^directory must not be empty, got ''$"):
        io.remove_temp_files("")


def test_write_pfm_refuses_values_beyond_float32(tmp_path: Path) -> None:
    """A finite float64 value beyond float32's range became an infinity in the file (only
    numpy's RuntimeWarning 'overflow encountered in cast'), which Middlebury's tools read as
    'unknown': refused, naming the value and its pixel, writing nothing. The largest float32
    and NaN / infinities are written as they are."""
    a = np.ones((2, 3))
    a[1, 2] = -1e39
    with pytest.raises(
        ValueError, match=r"array must fit in float32 .* got -1e\+39 at row 1, column 2"
    ):
        io.write_pfm(tmp_path / "x.pfm", a)
    assert names(tmp_path) == []
    top = float(np.finfo(np.float32).max)
    b = np.array([[top, -top, np.nan], [np.inf, -np.inf, 1e-50]])
    io.write_pfm(tmp_path / "y.pfm", b)
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "y.pfm"), b.astype(np.float32))


def _pair(folder: Path) -> tuple[str, str]:
    rng = np.random.default_rng(1)
    left = rng.integers(0, 255, (64, 128), dtype=np.uint8)
    Image.fromarray(left).save(folder / "l.png")
    Image.fromarray(np.roll(left, -5, axis=1)).save(folder / "r.png")
    return str(folder / "l.png"), str(folder / "r.png")


def test_images_over_pillows_warning_size_read_without_its_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # From Image.MAX_IMAGE_PIXELS (89.5 MP) to twice that Pillow warns: a 12000 x 12000 pair
    # printed its DecompressionBombWarning (2 lines with a source path) under match's output.
    # Here Pillow's limit is lowered to put a 64 x 128 pair in that range.
    import warnings

    from stereodepth import cli

    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 5000)
    left, right = _pair(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert io.read_image(left).shape == (64, 128)
        assert io._sample_dtype(left) == np.uint8
        code = cli.main(["match", left, right, "-o", f"{tmp_path}/out/", "--no-preview"])
    assert code == 0
    assert capsys.readouterr().err == ""


def test_a_large_image_is_read_without_a_warning(tmp_path: Path) -> None:
    import warnings

    side = 9500  # 90.25 MP, over Pillow's 89.5 MP warning size
    Image.fromarray(np.zeros((side, side), np.uint8)).save(tmp_path / "big.png")
    before = list(warnings.filters)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert io.read_image(tmp_path / "big.png").shape == (side, side)
    assert warnings.filters == before


def test_more_than_max_image_pixels_names_the_file_and_its_size(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from stereodepth import cli

    monkeypatch.setattr(io, "MAX_IMAGE_PIXELS", 8000)
    left, right = _pair(tmp_path)
    with pytest.raises(ValueError, match=r"l\.png: 128 x 64 pixels is more than the 8,000 "):
        io.read_image(left)
    assert cli.main(["match", left, right, "-o", f"{tmp_path}/out/", "--no-preview"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stereodepth match: error: LEFT: ") and err.count("\n") == 1
    assert "128 x 64 pixels" in err
