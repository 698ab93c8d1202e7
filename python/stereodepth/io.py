"""Reading and writing images and maps: PNG (8/16-bit), PFM, and atomic writes.

Needs Pillow for PNG (the ``batch`` extra): ``pip install "stereodepth[batch]"``.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

__all__ = [
    "TEMP_MARKER",
    "atomic_write",
    "read_image",
    "read_pfm",
    "remove_temp_files",
    "write_disparity_png16",
    "write_npy",
    "write_pfm",
    "write_png16",
]

#: Part of the name of every temporary file atomic_write creates: ``.<name>.<TEMP_MARKER>-*.tmp``.
TEMP_MARKER = "stereodepth"


def _pil() -> Any:
    try:
        from PIL import Image
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError('reading images needs Pillow: pip install "stereodepth[batch]"') from exc
    return Image


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """An image file as a numpy array: (H, W) uint8 or uint16 grey, or (H, W, 3) uint8 RGB.

    Palette and grey-alpha images become grey or RGB; an alpha channel is dropped. Raises
    FileNotFoundError for a missing file and ValueError naming the file when it cannot be
    decoded."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"image not found: {p}")
    Image = _pil()
    try:
        with Image.open(p) as im:
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I;16L"):
                return np.asarray(im, dtype=np.uint16)
            if mode == "I":
                arr = np.asarray(im)
                if arr.min() < 0 or arr.max() > 65535:
                    raise ValueError(f"{p}: 32-bit image values outside 0..65535")
                return arr.astype(np.uint16)
            if mode == "L":
                return np.asarray(im, dtype=np.uint8)
            if mode in ("1", "P", "LA", "PA"):
                im2 = im.convert("RGBA" if mode in ("P", "PA") else "L")
                if im2.mode == "RGBA":
                    rgb = np.asarray(im2.convert("RGB"), dtype=np.uint8)
                    if (rgb[..., 0] == rgb[..., 1]).all() and (rgb[..., 1] == rgb[..., 2]).all():
                        return np.ascontiguousarray(rgb[..., 0])
                    return rgb
                return np.asarray(im2, dtype=np.uint8)
            return np.asarray(im.convert("RGB"), dtype=np.uint8)
    except (OSError, SyntaxError) as exc:  # Pillow's errors for truncated / corrupt files
        raise ValueError(f"cannot decode image {p}: {exc}") from exc


# --- atomic writes ----------------------------------------------------------------------------
def _temp_path(p: Path) -> Path:
    return p.with_name(f".{p.name}.{TEMP_MARKER}-{secrets.token_hex(6)}.tmp")


def _fsync_dir(d: Path) -> None:
    if os.name != "posix":  # pragma: no cover - directories cannot be opened on Windows
        return
    fd = os.open(d, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str], *, text: bool = False) -> Iterator[IO[Any]]:
    """Writes a file so that it is either absent or complete, never half-written.

    Yields a file opened for writing (binary, or UTF-8 text with ``text=True``) on a temporary
    file in the same directory (``.<name>.stereodepth-<random>.tmp``). When the block ends
    normally the data is flushed and fsynced and the temporary file renamed over ``path``
    (atomic on POSIX and Windows); when it raises, including KeyboardInterrupt, the temporary
    file is removed and ``path`` is untouched. A process killed outright can leave a
    temporary file behind, never a partial ``path``: :func:`remove_temp_files` sweeps them.
    """
    p = Path(path)
    tmp = _temp_path(p)
    # O_EXCL: never follow or clobber anything; mode 0o666 so the umask applies as usual.
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        f: IO[Any] = os.fdopen(fd, "w", encoding="utf-8") if text else os.fdopen(fd, "wb")
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _fsync_dir(p.parent)


_TEMP_RE = re.compile(r"^\..+\." + TEMP_MARKER + r"-[0-9a-f]{12}\.tmp$")


def remove_temp_files(directory: str | os.PathLike[str]) -> list[Path]:
    """Removes the temporary files :func:`atomic_write` left in ``directory`` (not recursive)
    when a process was killed mid-write. Only call it when no other process is writing there.
    Returns the paths removed."""
    removed: list[Path] = []
    d = Path(directory)
    if not d.is_dir():
        return removed
    for entry in d.iterdir():
        if _TEMP_RE.match(entry.name) and entry.is_file():
            with contextlib.suppress(FileNotFoundError):
                entry.unlink()
                removed.append(entry)
    return removed


# --- writers ----------------------------------------------------------------------------------
def write_npy(path: str | os.PathLike[str], array: np.ndarray) -> None:
    """``numpy.save`` to exactly ``path`` (no ``.npy`` appended), atomically."""
    with atomic_write(path) as f:
        np.save(f, np.asarray(array), allow_pickle=False)


def _check_2d(name: str, array: Any, dtypes: tuple[type, ...]) -> np.ndarray:
    if not isinstance(array, np.ndarray):
        raise TypeError(f"{name} must be a numpy.ndarray, got {type(array).__name__}")
    if array.dtype not in dtypes:
        allowed = " or ".join(np.dtype(t).name for t in dtypes)
        raise TypeError(f"{name} must have dtype {allowed}, got {array.dtype}")
    if array.ndim != 2 or 0 in array.shape:
        raise ValueError(f"{name} must be a non-empty (H, W) array, got shape {array.shape}")
    return array


def write_png16(
    path: str | os.PathLike[str], array: np.ndarray, *, compress_level: int = 1
) -> None:
    """A (H, W) uint16 array as a 16-bit greyscale PNG, atomically (for depth in millimetres
    from ``disparity_to_depth(..., dtype=numpy.uint16)``: 0 means no depth).

    ``compress_level`` is zlib's, 0 to 9. The default 1 writes a depth map about 4 times as
    fast as Pillow's default 6, in files 10 to 20 % larger."""
    a = _check_2d("array", array, (np.uint16,))
    if isinstance(compress_level, bool) or not isinstance(compress_level, int):
        raise TypeError(f"compress_level must be an integer, got {compress_level!r}")
    if not 0 <= compress_level <= 9:
        raise ValueError(f"compress_level must be an integer in [0, 9], got {compress_level}")
    Image = _pil()
    im = Image.fromarray(np.ascontiguousarray(a))  # mode I;16
    with atomic_write(path) as f:
        im.save(f, format="PNG", compress_level=compress_level)


def write_disparity_png16(path: str | os.PathLike[str], disparity: np.ndarray) -> None:
    """A float disparity map in KITTI's format, atomically: uint16 PNG of round(d * 256), 0
    where the disparity is NaN, infinite, <= 0 or too small to encode (< 1/512 px), capped at
    65535 (255.996 px). Read back with ``read_image(path) / 256``."""
    d = _check_2d("disparity", disparity, (np.float32, np.float64)).astype(np.float64)
    ok = np.isfinite(d) & (d > 0)
    v = np.minimum(np.rint(np.where(ok, d, 0.0) * 256.0), 65535.0)
    write_png16(path, v.astype(np.uint16))


def write_pfm(path: str | os.PathLike[str], array: np.ndarray, *, scale: float = 1.0) -> None:
    """A (H, W) or (H, W, 3) float array as PFM (float32, little-endian), atomically.

    PFM stores rows bottom to top; NaN and infinities are kept as they are (Middlebury's tools
    read infinity as "unknown"; stereodepth writes NaN)."""
    a = np.asarray(array)
    if a.dtype.kind != "f":
        raise TypeError(f"array must have a float dtype, got {a.dtype}")
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)) or 0 in a.shape:
        raise ValueError(f"array must have shape (H, W) or (H, W, 3), got {a.shape}")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a finite number > 0, got {scale!r}")
    kind = "Pf" if a.ndim == 2 else "PF"
    height, width = a.shape[:2]
    header = f"{kind}\n{width} {height}\n{-float(scale)}\n".encode("ascii")
    body = np.ascontiguousarray(a[::-1], dtype="<f4")
    with atomic_write(path) as f:
        f.write(header)
        f.write(body.tobytes())


def read_pfm(path: str | os.PathLike[str]) -> np.ndarray:
    """A PFM file as float32 (H, W) or (H, W, 3), rows top to bottom, in native byte order.

    Raises FileNotFoundError for a missing file and ValueError naming the file when its
    header or size is wrong."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"PFM file not found: {p}")
    data = p.read_bytes()
    # The header: three whitespace-separated tokens after the magic, each writer laying out
    # the line breaks a little differently; one whitespace byte ends it.
    m = re.match(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)\s", data)
    if m is None:
        raise ValueError(f"{p}: not a PFM file (header {data[:32]!r})")
    channels = 3 if m.group(1) == b"PF" else 1
    width, height = int(m.group(2)), int(m.group(3))
    try:
        scale = float(m.group(4))
    except ValueError as exc:
        raise ValueError(f"{p}: bad PFM scale {m.group(4)!r}") from exc
    if scale == 0:
        raise ValueError(f"{p}: bad PFM scale 0 (its sign gives the byte order)")
    dtype = np.dtype("<f4" if scale < 0 else ">f4")
    count = width * height * channels
    body = data[m.end() :]
    if len(body) < count * 4:
        raise ValueError(
            f"{p}: truncated PFM: {width}x{height}x{channels} needs {count * 4} bytes of data, "
            f"got {len(body)}"
        )
    a = np.frombuffer(body, dtype=dtype, count=count)
    shape = (height, width) if channels == 1 else (height, width, 3)
    return a.reshape(shape)[::-1].astype(np.float32)  # native order, top to bottom, a copy
