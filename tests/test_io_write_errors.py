"""stereodepth.io writers: every error names the path or the parameter at fault, and leaves
what was there as it was."""

from __future__ import annotations

import errno
import importlib.util
import os
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from stereodepth import io
from stereodepth.pointcloud import write_ply

DISPARITY = np.arange(20, dtype=np.float32).reshape(4, 5) + 1


def writers(*, colour: bool = True) -> dict[str, Callable[[Path], Any]]:
    """Every writer that goes through io.atomic_write, by the extension it writes; with
    ``colour``, save_colorized too (it checks its path's name and folder itself, first)."""
    out: dict[str, Callable[[Path], Any]] = {
        "pfm": lambda p: io.write_pfm(p, DISPARITY),
        "npy": lambda p: io.write_npy(p, DISPARITY),
        "png": lambda p: io.write_png16(p, DISPARITY.astype(np.uint16)),
        "kitti.png": lambda p: io.write_disparity_png16(p, DISPARITY),
        "disp.pfm": lambda p: io.write_disparity_pfm(p, DISPARITY),
        "bin": lambda p: write_through_atomic_write(p),
    }
    if colour and importlib.util.find_spec("matplotlib") is not None:  # the plot extra
        from stereodepth import save_colorized

        out["colour.png"] = lambda p: save_colorized(p, DISPARITY)
    return out


def write_through_atomic_write(p: Path) -> None:
    with io.atomic_write(p) as f:
        f.write(b"x" * 100_000)


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full (Linux)")
@pytest.mark.parametrize("kind", [*writers(colour=False), "ply"])
def test_a_full_disk_names_the_path(kind: str) -> None:
    """write_pfm('/dev/full', a) said "[Errno 28] No space left on device", naming nothing:
    in a batch of files, which one? Every writer names it, as write_ply did."""
    write = writers()[kind] if kind != "ply" else lambda p: write_ply(p, np.ones((3, 3)))
    with pytest.raises(OSError, match="No space left on device") as info:
        write(Path("/dev/full"))
    assert info.value.errno == errno.ENOSPC
    assert info.value.filename == "/dev/full"
    assert "No space left on device" in str(info.value) and "/dev/full" in str(info.value)


@pytest.mark.skipif(sys.platform == "win32", reason="resource limits")
def test_a_failed_write_to_a_regular_file_names_the_path(tmp_path: Path) -> None:
    """A write that fails part way into the temporary file (EFBIG here, under a file-size
    limit; ENOSPC on a full disk) named no file: now the user's path, never the temporary
    file, which is removed, the old file kept."""
    for ext in writers():
        (tmp_path / f"out.{ext}").write_bytes(b"old")
    script = textwrap.dedent(f"""
        import resource, signal
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        import numpy as np
        from pathlib import Path
        import test_io_write_errors as t
        resource.setrlimit(resource.RLIMIT_FSIZE, (64, 64))
        for ext, write in t.writers().items():
            try:
                write(Path({str(tmp_path)!r}) / f"out.{{ext}}")
            except OSError as exc:
                print(ext, exc.errno, exc.filename, exc, sep="|")
    """)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).parent), *sys.path]))
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert [line.split("|")[0] for line in lines] == list(writers())
    for line in lines:
        ext, code, filename, message = line.split("|")
        target = str(tmp_path / f"out.{ext}")
        assert int(code) == errno.EFBIG and filename == target, line
        assert (
            message == f"[Errno {errno.EFBIG}] cannot write out.{ext}: File too large: {target!r}"
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"out.{e}" for e in writers())
    assert all(p.read_bytes() == b"old" for p in tmp_path.iterdir())


def test_a_file_where_a_folder_should_be_is_named_as_one(tmp_path: Path) -> None:
    """write_pfm('afile/x.pfm') with afile a regular file said only "Not a directory"; a
    missing folder "No such file or directory". Both now say which part is at fault."""
    afile = tmp_path / "afile"
    afile.write_bytes(b"mine")
    for ext, write in writers(colour=False).items():
        for target in (afile / f"x.{ext}", afile / "sub" / f"x.{ext}"):
            with pytest.raises(NotADirectoryError) as info:
                write(target)
            assert info.value.filename == str(target)
            assert str(info.value) == (
                f"[Errno {errno.ENOTDIR}] cannot write x.{ext}: {str(afile)!r} is a file, not "
                f"a folder: {str(target)!r}"
            )
        target = tmp_path / "missing" / "deeper" / f"x.{ext}"
        with pytest.raises(FileNotFoundError) as info:
            write(target)
        assert info.value.filename == str(target)
        assert f"cannot write x.{ext}: the folder {str(target.parent)!r} does not exist" in str(
            info.value
        )
    assert afile.read_bytes() == b"mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_every_writer_with_its_own_folder_check_names_a_file_in_the_way(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # write_ply, save_colorized, save_charts, `calc --plot` and `batch --report` check their
    # folder themselves; each called a regular file in the way a folder that "does not exist".
    from stereodepth import StereoRig, save_colorized
    from stereodepth.cli import main
    from stereodepth.plotting import save_charts

    (tmp_path / "afile").write_bytes(b"mine")
    inside = tmp_path / "afile"
    with pytest.raises(NotADirectoryError, match="is a file, not a folder"):
        write_ply(inside / "x.ply", np.ones((3, 3)))
    with pytest.raises(FileNotFoundError, match=r"the folder .*nowhere' does not exist"):
        write_ply(tmp_path / "nowhere" / "x.ply", np.ones((3, 3)))
    if importlib.util.find_spec("matplotlib") is not None:  # the plot extra
        with pytest.raises(ValueError, match=r"afile' is a file, not a folder"):
            save_colorized(inside / "c.png", np.ones((3, 3)))
        rig = StereoRig.from_pixels(baseline_mm=100, focal_px=700)
        with pytest.raises(ValueError, match=r"afile' is a file, not a folder"):
            save_charts(rig, inside / "c.png")
    plot = ["calc", "--baseline-mm", "100", "--focal-px", "700", "--disparity-px", "35"]
    assert main([*plot, "--plot", str(inside / "c.png")]) == 2
    err = capsys.readouterr().err
    assert "afile' is a file, not a folder" in err and err.count("\n") == 1
    assert inside.read_bytes() == b"mine"


@pytest.mark.parametrize(
    ("array", "exc", "message"),
    [
        (np.array([1, "a"], object), TypeError, r"^array must not hold Python objects \(dtype "),
        (
            np.zeros(2, [("a", "f4"), ("b", object)]),
            TypeError,
            r"^array must not hold Python objects \(dtype \[\('a', '<f4'\), \('b', 'O'\)\]",
        ),
        ([[1, 2], [3]], ValueError, r"^array must be a numpy array or a sequence .*got a list"),
        (np.ma.masked_array([1.0, 2.0], [True, False]), TypeError, r"array"),
    ],
)
def test_write_npy_refuses_what_npy_cannot_hold(
    tmp_path: Path, array: Any, exc: type, message: str
) -> None:
    """An object array reached numpy.save, whose "Object arrays cannot be saved when
    allow_pickle=False" named no parameter; refused up front, naming array, nothing written."""
    target = tmp_path / "a.npy"
    target.write_bytes(b"old")
    with pytest.raises(exc, match=message):
        io.write_npy(target, array)
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npy"]


def test_write_npy_still_writes_what_npy_holds(tmp_path: Path) -> None:
    for a in (
        np.arange(6, dtype=">i2").reshape(2, 3),
        np.array(["ab", "c"]),
        np.zeros(2, [("x", "f4"), ("y", "u1")]),
        np.array(True),
        [[1.5, 2.5]],
    ):
        io.write_npy(tmp_path / "a.npy", a)  # type: ignore[arg-type]
        np.testing.assert_array_equal(np.load(tmp_path / "a.npy"), np.asarray(a), strict=True)
