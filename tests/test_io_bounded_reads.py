"""stereodepth.io: PFM and PNM readers check a header against the file's size before reading
the body, and name the file when memory runs out."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import test_io

from stereodepth import io

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="resource limits, sparse files")

GB = 1 << 30


def sparse(path: Path, head: bytes, size: int) -> Path:
    """``head`` then zeros up to ``size`` bytes, without writing the zeros (a sparse file)."""
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(size)
    return path


def run_limited(code: str, limit: int = 2 * GB) -> subprocess.CompletedProcess[str]:
    """``code`` in a Python whose address space is capped at ``limit`` bytes (set after the
    imports), so that reading a file of several GB whole fails as it would on a small machine
    rather than filling this one."""
    script = "import resource\nimport numpy as np\nfrom stereodepth import io\n"
    script += f"resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))\n"
    script += textwrap.dedent(code)
    return subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False
    )


#: Binary headers whose bodies are 24 bytes, and their descriptions in messages.
BINARY = {
    "a.pfm": (b"Pf\n3 2\n-1\n", "3x2x1 PFM"),
    "a.pgm": (b"P5\n4 6\n255\n", "4x6 PGM with maxval 255"),
    "a.ppm": (b"P6\n2 2\n65535\n", "2x2 PPM with maxval 65535"),
    "a.pbm": (b"P4\n9 12\n", "9x12 PBM"),
}


def test_a_padded_binary_file_is_refused_without_reading_it(tmp_path: Path) -> None:
    """A 24-byte body padded to 8 GB: read whole first, it took a minute and 8 GB of memory
    before "has ... bytes more than its header", or a bare MemoryError under a limit. The
    header's size against the file's refuses it at once, in a process that cannot hold it."""
    size = 8 * GB
    cases = {name: str(sparse(tmp_path / name, head, size)) for name, (head, _) in BINARY.items()}
    result = run_limited(f"""
        import time
        for path in {list(cases.values())!r}:
            t = time.perf_counter()
            read = io.read_pfm if path.endswith(".pfm") else io.read_pnm
            try:
                read(path)
            except Exception as exc:
                print(type(exc).__name__, round(time.perf_counter() - t, 3), exc, sep="|")
    """)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == len(BINARY), result.stdout
    for line, (name, (head, desc)) in zip(lines, BINARY.items(), strict=True):
        kind, seconds, message = line.split("|", 2)
        extra = size - len(head) - 24
        assert kind == "ValueError", line
        assert message == (
            f"{tmp_path / name}: {desc} has {extra} bytes more than its header and 24 bytes of data"
        )
        assert float(seconds) < 1.0, line


def test_a_file_too_large_for_memory_is_named(tmp_path: Path) -> None:
    """A file of the size its header gives that does not fit in memory, and a plain (ASCII)
    raster (no exact size: read whole) larger than memory: a MemoryError naming the file and
    the size, where it was a MemoryError with an empty message."""
    head = b"P5\n60000 60000\n65535\n"
    pgm = sparse(tmp_path / "big.pgm", head, len(head) + 60000 * 60000 * 2)
    head = b"PF\n30000 30000\n-1\n"
    pfm = sparse(tmp_path / "big.pfm", head, len(head) + 30000 * 30000 * 12)
    plain = sparse(tmp_path / "plain.pgm", b"P2\n1 1\n255\n1", 4 * GB)
    result = run_limited(f"""
        for read, path in [(io.read_pnm, {str(pgm)!r}), (io.read_pfm, {str(pfm)!r}),
                           (io.read_pnm, {str(plain)!r}), (io.read_image, {str(pgm)!r})]:
            try:
                read(path)
            except MemoryError as exc:
                print(exc)
    """)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == [
        f"{pgm}: not enough memory to read the 60000x60000 PGM with maxval 65535 "
        f"({60000 * 60000 * 2} bytes of data)",
        f"{pfm}: not enough memory to read the 30000x30000x3 PFM ({30000 * 30000 * 12} bytes "
        "of data)",
        f"{plain}: not enough memory to read the plain (ASCII) 1x1 PGM with maxval 255 "
        f"({4 * GB} bytes)",
        f"{pgm}: not enough memory to read the 60000x60000 PGM with maxval 65535 "
        f"({60000 * 60000 * 2} bytes of data)",
    ]


def cases(test: Any) -> list[Any]:
    """The parameter sets of one of test_io's parametrized tests (its innermost
    ``parametrize``)."""
    mark = next(m for m in test.pytestmark if m.name == "parametrize")
    return list(mark.args[1])


@pytest.mark.parametrize("head_bytes", [1, 2, 3, 5, 8, 13])
def test_headers_read_in_small_parts_give_the_same_answers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, head_bytes: int
) -> None:
    """The header is parsed from the file's first bytes, more of them when it goes on: a
    number, a comment or a line end cut where a read ends must read as the whole file does.
    Every accepted and refused file of test_io, read a few bytes at a time."""
    monkeypatch.setattr(io, "_HEAD_BYTES", head_bytes)
    for content, message in cases(test_io.test_read_pfm_rejects):
        (tmp_path / "bad.pfm").write_bytes(content)
        with pytest.raises(ValueError, match=r"^\S*bad\.pfm: (.* )?" + message):
            io.read_pfm(tmp_path / "bad.pfm")
    for content, message in cases(test_io.test_read_pnm_rejects):
        (tmp_path / "bad.pgm").write_bytes(content)
        with pytest.raises(ValueError, match=r"^\S*bad\.pgm: (.* )?" + message):
            io.read_pnm(tmp_path / "bad.pgm")
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    for header in [m.args[1] for m in test_io.test_pfm_header_layouts.pytestmark][1]:
        for prefix in (b"\n", b"\r", b"\r\n", b"1"):
            a[1, 0] = test_io.float_starting_with(prefix)
            (tmp_path / "a.pfm").write_bytes(test_io.pfm_bytes(a, header))
            np.testing.assert_array_equal(io.read_pfm(tmp_path / "a.pfm"), a, strict=True)
    for header, want in cases(test_io.test_pnm_binary):
        (tmp_path / "a.pnm").write_bytes(test_io.pgm(header, want))
        np.testing.assert_array_equal(io.read_pnm(tmp_path / "a.pnm"), want, strict=True)


def test_a_header_longer_than_the_first_read(tmp_path: Path) -> None:
    """netpbm comments have no length limit: a header of 200 kB (beyond the first 64 kB read)
    is read in larger parts, and its body checked and read as any other."""
    comment = b"# " + b"x" * 200_000 + b"\n"
    a = np.array([[1, 2, 3], [4, 5, 65535]], np.uint16)
    (tmp_path / "a.pgm").write_bytes(test_io.pgm(b"P5\n" + comment + b"3 2\n65535\n", a))
    np.testing.assert_array_equal(io.read_pnm(tmp_path / "a.pgm"), a, strict=True)
    (tmp_path / "b.pgm").write_bytes(test_io.pgm(b"P5\n" + comment + b"3 2\n65535\n", a) + b"!")
    with pytest.raises(ValueError, match=r"b\.pgm: 3x2 PGM with maxval 65535 has 1 bytes more"):
        io.read_pnm(tmp_path / "b.pgm")
    pfm = b"Pf\n3 2" + b" " * 100_000 + b"\n-1\n"  # whitespace between fields: no limit either
    f = np.arange(6, dtype=np.float32).reshape(2, 3)
    (tmp_path / "a.pfm").write_bytes(test_io.pfm_bytes(f, pfm))
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "a.pfm"), f, strict=True)
