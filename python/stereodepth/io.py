"""Reading and writing images and maps: PNG (8/16-bit), PFM, PBM/PGM/PPM, and atomic writes.

PFM and netpbm headers are parsed exactly (see :func:`read_pfm`, :func:`read_pnm`): a file
whose header or size does not add up is refused, never read shifted. Needs Pillow for PNG
(the ``batch`` extra): ``pip install "stereodepth[batch]"``.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import os
import re
import secrets
import stat
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from . import _validate as check
from ._validate import native_order

__all__ = [
    "MAX_IMAGE_PIXELS",
    "TEMP_MARKER",
    "atomic_write",
    "read_disparity_pfm",
    "read_disparity_png16",
    "read_image",
    "read_pfm",
    "read_pnm",
    "remove_temp_files",
    "write_disparity_pfm",
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


#: The most pixels :func:`read_image` reads from a file Pillow decodes: Pillow's own refusal
#: (twice its ``Image.MAX_IMAGE_PIXELS``, 89,478,485 by default). Pillow warns
#: (``DecompressionBombWarning``) from its ``MAX_IMAGE_PIXELS`` up: read_image reads those
#: images (a 12000 x 12000 pair) without that warning, and refuses larger ones with a
#: ValueError naming the file and its size.
MAX_IMAGE_PIXELS = 2 * 89_478_485

# warnings' filters are process-wide: reads that silence Pillow's warning take turns, so that
# none restores the filters another had changed.
_PIL_WARNINGS_LOCK = threading.Lock()


@contextlib.contextmanager
def _no_bomb_warning(Image: Any) -> Iterator[None]:
    """Pillow's DecompressionBombWarning silenced for one read (its ``MAX_IMAGE_PIXELS``
    is not our limit: :data:`MAX_IMAGE_PIXELS` is, checked by :func:`_pil_open`)."""
    with _PIL_WARNINGS_LOCK, warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        yield


def _bomb_pixels(exc: Exception) -> int | None:
    """The pixel count in Pillow's decompression-bomb message ("Image size (N pixels)
    exceeds limit ..."), or None when it has none."""
    got = re.search(r"\((\d+) pixels\)", str(exc))
    return int(got[1]) if got else None


def _pil_open(Image: Any, p: Path) -> tuple[Any, bool]:
    """``Image.open(p)`` (the header only) without Pillow's DecompressionBombWarning, and
    whether the image is over Pillow's ``MAX_IMAGE_PIXELS`` (its decoding, where some
    formats check again, is then to be silenced too). ValueError naming the file and its
    size when it is over :data:`MAX_IMAGE_PIXELS` or what Pillow opens."""
    with _no_bomb_warning(Image):
        try:
            im = Image.open(p)
        except Image.DecompressionBombError as exc:  # Image.MAX_IMAGE_PIXELS lowered
            count = _bomb_pixels(exc)
            n = f"{count:,} pixels" if count is not None else "more pixels"
            raise ValueError(
                f"cannot decode image {p}: {n}, more than the "
                f"{2 * (Image.MAX_IMAGE_PIXELS or 0):,} Pillow opens (twice "
                "PIL.Image.MAX_IMAGE_PIXELS)"
            ) from None
    w, h = im.size
    if w * h > MAX_IMAGE_PIXELS:
        im.close()
        raise ValueError(
            f"cannot decode image {p}: {w} x {h} pixels is more than the {MAX_IMAGE_PIXELS:,} "
            "stereodepth reads"
        )
    limit = Image.MAX_IMAGE_PIXELS
    return im, limit is not None and w * h > limit


#: The EXIF orientation tag (TIFF tag 274): how the stored pixels are to be turned for display.
_ORIENTATION = 0x0112


def upright(im: Any) -> Any:
    """A loaded Pillow image turned as its EXIF orientation tag says (values 2 to 8: mirrored
    and/or rotated by 90, 180 or 270 degrees), as ``cv2.imread`` (``IMREAD_COLOR`` and
    ``IMREAD_GRAYSCALE``) and web browsers show it; the image itself when it has no such tag
    or the tag is 1. Source: the EXIF 2.32 specification, tag 0x0112 (Orientation)."""
    try:
        orientation = im.getexif().get(_ORIENTATION, 1)
    except (OSError, ValueError, SyntaxError):  # unreadable EXIF: as stored
        return im
    if orientation not in (2, 3, 4, 5, 6, 7, 8):
        return im
    from PIL import ImageOps

    return ImageOps.exif_transpose(im)


def require_file(path: str | os.PathLike[str], what: str) -> Path:
    """``path`` as a Path when it names an existing regular file (or a link to one).

    Raises FileNotFoundError ("{what} not found: path") when nothing is there (or "{what}
    is not a regular file (a device, pipe or socket): path" for one of those, which reading
    could block on or never end) and IsADirectoryError ("{what} is a folder, not a file:
    path") for a folder, so that a user who passed a folder is not told the file is missing.
    """
    p = _as_path(path)
    if p.is_dir():
        raise IsADirectoryError(f"{what} is a folder, not a file: {p}")
    if not p.is_file():
        if p.exists():
            raise FileNotFoundError(f"{what} is not a regular file (a device, pipe or socket): {p}")
        raise FileNotFoundError(f"{what} not found: {p}")
    return p


def _as_path(value: Any, name: str = "path") -> Path:
    """``value`` as a Path; TypeError naming ``name`` for anything but a str or os.PathLike
    (pathlib's own message, "expected str, bytes or os.PathLike object, not int", named no
    parameter; bytes paths are refused as pathlib refuses them), ValueError for an empty str
    (pathlib reads "" as ".", the current folder: an unset variable in a script read or
    wrote there, or was told "is a folder, not a file: .")."""
    if isinstance(value, str) and not value:
        raise ValueError(f"{name} must not be empty, got ''")
    if isinstance(value, str) or (
        isinstance(value, os.PathLike) and isinstance(os.fspath(value), str)
    ):
        return Path(value)
    raise TypeError(f"{name} must be a str or os.PathLike, got {type(value).__name__} {value!r}")


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """An image file as a numpy array: (H, W) uint8 or uint16 grey, or (H, W, 3) uint8 RGB.

    PBM, PGM and PPM files (netpbm P1 to P6, told by their first two bytes) are read by
    :func:`read_pnm`, exactly, with their samples as stored (a 16-bit PPM gives (H, W, 3)
    uint16); every other format by Pillow. Palette and grey-alpha images become grey or RGB;
    an alpha channel is dropped. An EXIF orientation tag (JPEG, PNG, TIFF) is applied, as
    ``cv2.imread`` applies it (:func:`upright`): the array is the image as displayed, in the
    pixel frame a calibration made from OpenCV-read images refers to.

    Raises FileNotFoundError for a missing file, IsADirectoryError for a folder and
    ValueError naming the file when it cannot be decoded (or has more than
    :data:`MAX_IMAGE_PIXELS`, 179 megapixels, what Pillow opens; Pillow's
    ``DecompressionBombWarning`` for images above half that is not shown), holds floating-point
    samples (a float TIFF or a PFM: :func:`read_pfm` reads those) or is 16-bit colour or
    16-bit with alpha (Pillow would keep only the high byte of each sample)."""
    return _read_image(_as_path(path), turn=True)


def _read_image(p: Path, *, turn: bool) -> np.ndarray:
    """:func:`read_image`, applying the EXIF orientation only with ``turn`` (a data map, such
    as a disparity PNG, is read as stored, as ``cv2.IMREAD_UNCHANGED`` and KITTI's devkit
    read it)."""
    require_file(p, "image")
    with p.open("rb") as f:
        magic = f.read(2)
    if magic in _PNM_KINDS:
        return read_pnm(p)
    Image = _pil()
    try:
        im, big = _pil_open(Image, p)
        with im:
            if im.mode not in _GREY16_MODES and any(";16" in m for m in _raw_modes(im)):
                # Pillow keeps only the high byte of these: 12-bit colour (0..4095) would
                # become 0..15, an almost black image, silently.
                raw = _raw_modes(im)[0]
                raise ValueError(
                    f"{p}: a 16-bit {'grey and alpha' if raw.startswith('LA') else 'colour'} "
                    f"image (stored as {raw}) cannot be read without losing its low "
                    "byte; the matchers take 16-bit grey or 8-bit colour: convert it to one "
                    "of those"
                )
            with _no_bomb_warning(Image) if big else contextlib.nullcontext():
                im.load()
            if turn:
                im = upright(im)
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
            if mode == "F" or mode.startswith("F;"):
                # Converting would quantise (0..1 becomes all black): not an image to match.
                raise ValueError(
                    f"{p}: a floating-point image (mode {mode}) is not an 8- or 16-bit image; "
                    "read disparity or depth maps with read_pfm"
                )
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


_GREY16_MODES = ("I;16", "I;16B", "I;16L", "I")


def _sample_dtype(path: str | os.PathLike[str]) -> np.dtype | None:
    """The dtype :func:`read_image` gives the image at ``path`` (uint8 or uint16), from its
    header alone: a PNM's (:func:`read_pnm`'s header parse), Pillow's mode before any pixel
    is decoded. None where the header does not say or :func:`read_image` would refuse the
    file (missing, unreadable, malformed; floating-point or 16-bit colour samples): reading
    it then gives its own message."""
    head = _image_header(path)
    return None if head is None else head[0]


def _header_size(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    """(width, height) of the image at ``path`` from its header alone, before any EXIF
    orientation (a quarter turn makes :func:`read_image`'s array (width, height) instead, and
    Pillow already turns some formats' sizes); None where the header cannot be read."""
    head = _image_header(path)
    return None if head is None else head[1]


def _image_header(path: str | os.PathLike[str]) -> tuple[np.dtype | None, tuple[int, int]] | None:
    """What :func:`_sample_dtype` and :func:`_header_size` read: the sample dtype (None for
    samples :func:`read_image` refuses) and the stored (width, height); None for a file whose
    header cannot be read."""
    p = Path(path)
    Image = _pil()
    try:
        with p.open("rb") as f:
            if f.read(2) in _PNM_KINDS:
                size = os.fstat(f.fileno()).st_size
                head = _parse_head(f, size, functools.partial(_pnm_head, p, file_size=size))
                return head[4], (int(head[1]), int(head[2]))
        im, _ = _pil_open(Image, p)
        with im:
            stored = (int(im.size[0]), int(im.size[1]))
            if im.mode in _GREY16_MODES:
                return np.dtype(np.uint16), stored
            if im.mode == "F" or im.mode.startswith("F;"):
                return None, stored
            if any(";16" in m for m in _raw_modes(im)):
                return None, stored
            return np.dtype(np.uint8), stored
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError):
        return None


def _raw_modes(im: Any) -> list[str]:
    """The raw modes of an opened (not yet loaded) Pillow image's tiles: how the file stores
    its samples (``RGB;16B`` for a 16-bit colour PNG, which Pillow reads as 8-bit RGB)."""
    modes = []
    for tile in getattr(im, "tile", None) or ():
        args = tile[3] if len(tile) > 3 else None
        raw = args if isinstance(args, str) else (args[0] if isinstance(args, tuple) else None)
        if isinstance(raw, str):
            modes.append(raw)
    return modes


# --- atomic writes ----------------------------------------------------------------------------
#: The longest file name, in bytes, of the file systems we write on (NAME_MAX on Linux and
#: macOS; NTFS allows 255 UTF-16 units, more than 255 bytes' worth of most names).
NAME_MAX_BYTES = 255


def _temp_path(p: Path) -> Path:
    """``.<name>.stereodepth-<random>.tmp`` beside ``p``; ``<name>`` shortened (whole
    characters) so the temporary name fits where ``p``'s own name fits: a name of 230 bytes or
    more could not be written, and the error named the temporary file."""
    tail = f".{TEMP_MARKER}-{secrets.token_hex(6)}.tmp"
    room = NAME_MAX_BYTES - 1 - len(tail.encode())
    name = p.name.encode(errors="surrogateescape")[:room].decode(errors="ignore") or "x"
    return p.with_name(f".{name}{tail}")


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
    (atomic on POSIX and Windows), which keeps the permissions of a file it replaces (on
    POSIX); when it raises, including KeyboardInterrupt, the temporary file is removed and
    ``path`` is untouched. A process killed outright can leave a
    temporary file behind, never a partial ``path``: :func:`remove_temp_files` sweeps them.
    A ``path`` that is a symbolic link is written through, as ``open``, ``numpy.save`` and
    ``cv2.imwrite`` write: the file it points to is replaced (its temporary file beside it)
    and the link kept, so that what the link names is the new file. A ``path`` that is a
    device, a pipe or a socket (``/dev/null``, ``/dev/stdout``, a FIFO) is written to as
    ``open`` writes it, never replaced by a file. A file without write permission is not
    replaced: PermissionError naming ``path``, as ``open`` refuses it.
    Raises IsADirectoryError naming ``path`` when it is a folder, before writing anything;
    the OSError of a folder that takes no new file naming ``path`` (FileNotFoundError "the
    folder '<folder>' does not exist", NotADirectoryError "'<part>' is a file, not a folder",
    PermissionError for a read-only one); and every OSError of writing, flushing, syncing or
    renaming (a full disk: ENOSPC, a file too large: EFBIG) as the same error type and errno
    naming ``path`` ("cannot write <name>: <reason>", its ``filename`` the path), never the
    temporary file, after removing that file. An OSError of the block that names another
    file, and every other exception, is raised as it is.
    """
    p = _as_path(path)
    if p.is_dir():  # else the rename's error names the temporary file, not the user's path
        raise IsADirectoryError(errno.EISDIR, "cannot write a file over a folder", str(p))
    if _is_stream(p):
        # Renaming over a device or a pipe replaced it by a regular file (with the right to:
        # as root, write_pfm("/dev/null", ...) made /dev/null a file); a stream has no
        # half-written state to avoid, so it is written as open() writes it.
        try:
            stream: IO[Any] = open(p, "w", encoding="utf-8") if text else open(p, "wb")  # noqa: SIM115
        except OSError as exc:  # a socket, or a device that takes no writes
            raise type(exc)(exc.errno, f"cannot write {p.name}: {exc.strerror}", str(p)) from None
        try:
            with stream:
                yield stream
        except OSError as exc:  # a full disk, a device that fails: name the path
            raise _naming(exc, p) from None
        return
    # A link is written through: replacing the link itself by the new file left the file
    # it named (on a shared disk, say) with the old data, and the link gone.
    target = Path(os.path.realpath(p)) if p.is_symlink() else p
    _refuse_read_only(target, p)
    tmp = _temp_path(target)
    # The file is created inside the block whose clean-up removes it: a Ctrl-C or SIGTERM
    # (raised between any two steps) that came just after it was created, before the block
    # began, left it behind.
    fd = -1
    f: IO[Any] | None = None
    refused = False  # os.open refused the name: nothing of ours to remove (it may be another's)
    try:
        # O_EXCL: never follow or clobber anything; mode 0o666 so the umask applies as usual.
        try:
            fd = os.open(
                tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666
            )
        except OSError as exc:
            # A folder that is missing, read-only or takes no new files (/proc), or a file
            # where a folder should be: name the user's path, not the temporary one the user
            # never gave.
            refused = True
            why = folder_fault(target) if exc.errno in (errno.ENOENT, errno.ENOTDIR) else None
            raise type(exc)(
                exc.errno, f"cannot write {p.name}: {why or exc.strerror}", str(p)
            ) from None
        f = os.fdopen(fd, "w", encoding="utf-8") if text else os.fdopen(fd, "wb")
        with f:
            yield f
            f.flush()
            # A file replaced keeps its permissions (a new one gets 0o666 less the umask).
            if hasattr(os, "fchmod"):  # POSIX
                with contextlib.suppress(FileNotFoundError):
                    os.fchmod(f.fileno(), os.stat(target).st_mode & 0o7777)
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException as exc:
        if refused:  # raised as it is, naming the user's path
            raise
        if f is None and fd >= 0:  # interrupted before the file object took the descriptor
            with contextlib.suppress(OSError):
                os.close(fd)
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):  # a full disk: name the user's path, not the temporary one
            raise _naming(exc, p, tmp) from None
        raise
    try:
        _fsync_dir(target.parent)
    except OSError as exc:
        raise _naming(exc, p) from None


def _naming(exc: OSError, p: Path, *ours: Path) -> OSError:
    """``exc``, raised while writing ``p``, as the same error naming ``p`` ("cannot write
    <name>: <reason>", ``filename`` the path) when it named no file or only one of ``ours``
    (the temporary file): a full disk gave "[Errno 28] No space left on device" and no path.
    An error naming another file, or with no errno (not the system's), is returned as it is."""
    if exc.errno is None or exc.filename not in (None, *(str(o) for o in ours)):
        return exc
    return type(exc)(exc.errno, f"cannot write {p.name}: {exc.strerror}", str(p))


def folder_fault(target: str | os.PathLike[str]) -> str | None:
    """Why the folder of ``target`` takes no file, when a part of its path is missing ("the
    folder '<path>' does not exist") or is a file ("'<path>' is a file, not a folder"); None
    when neither (a permission the process lacks, say). Every writer's own folder check says
    it so (a file in the way was once called a folder that "does not exist")."""
    folder = Path(os.path.abspath(target)).parent
    for part in [*reversed(folder.parents), folder]:
        try:
            mode = os.stat(part).st_mode
        except FileNotFoundError:
            return f"the folder {str(folder)!r} does not exist"
        except OSError:
            return None
        if not stat.S_ISDIR(mode):
            return f"{str(part)!r} is a file, not a folder"
    return None


def no_folder_reason(target: str | os.PathLike[str]) -> str:
    """For a writer whose folder check failed: :func:`folder_fault`'s reason, or that the
    folder cannot be read (a permission the process lacks)."""
    folder = Path(os.path.abspath(target)).parent
    return folder_fault(target) or f"the folder {str(folder)!r} cannot be read"


def _is_read_only(target: str | os.PathLike[str]) -> bool:
    """Whether ``target`` (a link's target) is a regular file without write permission: no
    write bit at all (even where the process could write it, as root), or none for us."""
    try:
        mode = os.stat(target).st_mode
    except (OSError, ValueError):
        return False
    return stat.S_ISREG(mode) and (not (mode & 0o222) or not os.access(target, os.W_OK))


def _refuse_read_only(target: Path, p: Path) -> None:
    """PermissionError naming ``p`` when ``target`` is a file without write permission.

    open() refuses to overwrite such a file, but renaming over it needs only the folder's
    permission, so a file the user had made read-only (chmod a-w: an input, a result to
    keep) was replaced without a word. A file with no write bit at all is refused even where
    the process could write it (root), as ``rm`` asks before removing one."""
    if _is_read_only(target):
        raise PermissionError(
            errno.EACCES,
            f"cannot write {p.name}: the file is read-only (no write permission); make it "
            "writable or choose another path",
            str(p),
        )


def _is_stream(p: Path) -> bool:
    """Whether ``p`` (its link's target) exists and is a device, a pipe or a socket."""
    try:
        mode = os.stat(p).st_mode
    except (OSError, ValueError):
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


_TEMP_RE = re.compile(r"^\..+\." + TEMP_MARKER + r"-[0-9a-f]{12}\.tmp$")


def remove_temp_files(directory: str | os.PathLike[str]) -> list[Path]:
    """Removes the temporary files :func:`atomic_write` left in ``directory`` (not recursive)
    when a process was killed mid-write. Only call it when no other process is writing there.
    Returns the paths removed."""
    removed: list[Path] = []
    d = _as_path(directory, "directory")
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
    """``numpy.save`` of ``array`` (any shape and numeric, bool, string or structured dtype;
    a sequence numpy makes an array of) to exactly ``path`` (no ``.npy`` appended),
    atomically, in NumPy's ``.npy`` format (format version 1.0 to 3.0, as numpy chooses),
    without pickles.

    Raises TypeError naming ``array`` for a masked array (fill it first) or one holding Python
    objects (dtype object, or a structured dtype with an object field: ``.npy`` stores those
    only as pickles, which :func:`numpy.load` refuses by default), ValueError naming
    ``array`` for a sequence numpy cannot make an array of (a ragged list), both before
    writing anything, and OSError naming ``path`` when it cannot be written (see
    :func:`atomic_write`); ``path`` is then left as it was."""
    check.not_masked("array", array)
    try:
        a = np.asarray(array)
    except ValueError as exc:
        raise ValueError(
            "array must be a numpy array or a sequence numpy makes one of (rows of equal "
            f"length), got a {type(array).__name__} it cannot: {exc}"
        ) from None
    if a.dtype.hasobject:
        raise TypeError(
            f"array must not hold Python objects (dtype {a.dtype}: .npy stores them only as "
            "pickles, which numpy.load refuses by default); convert it to a numeric, bool or "
            "string dtype"
        )
    with atomic_write(path) as f:
        np.save(f, a, allow_pickle=False)


def _check_2d(name: str, array: Any, dtypes: tuple[type, ...]) -> np.ndarray:
    if not isinstance(array, np.ndarray):
        raise TypeError(f"{name} must be a numpy.ndarray, got {type(array).__name__}")
    check.not_masked(name, array)
    # A big-endian map is a map all the same: in the machine's byte order.
    a: np.ndarray = native_order(array)
    if a.dtype not in dtypes:
        allowed = " or ".join(np.dtype(t).name for t in dtypes)
        raise TypeError(f"{name} must have dtype {allowed}, got {a.dtype}")
    if a.ndim != 2 or 0 in a.shape:
        raise ValueError(f"{name} must be a non-empty (H, W) array, got shape {a.shape}")
    return a


def write_png16(
    path: str | os.PathLike[str], array: np.ndarray, *, compress_level: int = 1
) -> None:
    """A (H, W) uint16 array as a 16-bit greyscale PNG, atomically (for depth in millimetres
    from ``disparity_to_depth(..., dtype=numpy.uint16)``: 0 means no depth).

    ``compress_level`` is zlib's, 0 to 9. The default 1 writes a depth map about 4 times as
    fast as Pillow's default 6, in files 10 to 20 % larger."""
    a = _check_2d("array", array, (np.uint16,))
    # numpy integers too (a level read from an array or a config); bool and float are not.
    if isinstance(compress_level, (bool, np.bool_)) or not isinstance(
        compress_level, (int, np.integer)
    ):
        raise TypeError(f"compress_level must be an integer, got {compress_level!r}")
    level = int(compress_level)
    if not 0 <= level <= 9:
        raise ValueError(f"compress_level must be an integer in [0, 9], got {level}")
    Image = _pil()
    im = Image.fromarray(np.ascontiguousarray(a))  # mode I;16
    with atomic_write(path) as f:
        im.save(f, format="PNG", compress_level=level)


def write_disparity_png16(path: str | os.PathLike[str], disparity: np.ndarray) -> None:
    """A float disparity map in KITTI's format, atomically: a 16-bit greyscale PNG of
    round(d * 256), rounded half up (1/512 px gives 1, 3/512 px gives 2), and 0 for "no
    value" where the disparity is NaN, infinite, <= 0 or too small to encode (below 1/512 px,
    which rounds to 0): the format has no negative values.

    The format is the KITTI stereo devkit's (``disp_write.m``: ``uint16(d * 256)``, which
    rounds half away from zero, the same as half up for these positive values; 0 is invalid).
    ``disparity`` is a (H, W) float32 or float64 numpy array in pixels. Read back with
    :func:`read_disparity_png16` (not ``read_image(path) / 256``, which reads the holes as
    disparity 0, a point at infinity).

    Raises TypeError for anything else than such an array, ValueError for another shape or,
    writing nothing, for a finite disparity that rounds above the format's largest, 65535 /
    256 = 255.996 px (it was once capped there: a wrong value, not a hole): write PFM or
    ``.npy`` for larger search ranges; an OSError naming ``path`` when it cannot be written,
    ``path`` then left as it was."""
    d = _check_2d("disparity", disparity, (np.float32, np.float64)).astype(np.float64)
    ok = np.isfinite(d) & (d > 0)
    # Half up, exactly (numpy's rint rounds half to even and made exactly 1/512 px a hole):
    # d * 256 is exact in float64 (a power of two), and so is its fraction, but adding 0.5
    # first rounds the sum (0.49999999999999994 + 0.5 is 1.0).
    scaled = np.where(ok, d, 0.0) * 256.0
    whole = np.floor(scaled)
    v = whole + (scaled - whole >= 0.5)
    if v.max(initial=0.0) > 65535.0:
        raise ValueError(
            f"disparity up to {float(d[ok].max()):g} px does not fit a 16-bit disparity PNG "
            "(KITTI's d * 256 holds at most 255.996 px): write PFM or .npy instead"
        )
    write_png16(path, v.astype(np.uint16))


def read_disparity_png16(path: str | os.PathLike[str]) -> np.ndarray:
    """A disparity map in KITTI's format as (H, W) float32 pixels, NaN where there is none.

    The format (the KITTI stereo devkit's ``disp_read``, also what
    :func:`write_disparity_png16` writes): a 16-bit greyscale PNG of d * 256, 0 for "no
    value", read as stored (an EXIF orientation tag is not applied, as the devkit and
    ``cv2.IMREAD_UNCHANGED`` do not). Each value v > 0 gives v / 256 (exact in float32); 0
    gives NaN. Read as ``read_image(path) / 256``, the holes would be disparity 0: a valid
    disparity (a point at infinity) to :func:`stereodepth.metrics.evaluate` and every depth
    conversion.

    Raises FileNotFoundError for a missing file, IsADirectoryError for a folder and ValueError
    naming the file for one that is not a 16-bit grey image (an 8-bit PNG, a colour image: a
    preview or a visualisation, not the data; the devkit reads those as wrong values) or
    cannot be decoded."""
    p = _as_path(path)
    raw = _read_image(p, turn=False)  # a data map: as stored, whatever its EXIF tag says
    if raw.dtype != np.uint16 or raw.ndim != 2:
        kind = "a colour" if raw.ndim == 3 else f"an {raw.dtype.itemsize * 8}-bit grey"
        raise ValueError(
            f"{p}: a KITTI disparity PNG is a 16-bit grey image (d * 256, 0 for no value), got "
            f"{kind} image of shape {raw.shape}"
        )
    out: np.ndarray = raw.astype(np.float32) / np.float32(256.0)
    out[raw == 0] = np.nan
    return out


def write_pfm(path: str | os.PathLike[str], array: np.ndarray, *, scale: float = 1.0) -> None:
    """A (H, W) or (H, W, 3) float array as PFM (float32, little-endian), atomically.

    PFM stores rows bottom to top; NaN and infinities are kept as they are. For a disparity
    map to be read by Middlebury's tools, which take only +infinity as "unknown" (a NaN is
    scored as a disparity), write it with :func:`write_disparity_pfm`.

    Raises TypeError for a non-float ``array`` or a ``scale`` that is not a real number (a
    str, a bool) and ValueError for another shape, a finite value beyond float32's range
    (about 3.4e38: PFM stores float32, and it would become an infinity, which Middlebury
    reads as "unknown") or a ``scale`` that is not finite and > 0, writing nothing."""
    check.not_masked("array", array)
    a = np.asarray(array)
    if a.dtype.kind != "f":
        raise TypeError(f"array must have a float dtype, got {a.dtype}")
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)) or 0 in a.shape:
        raise ValueError(f"array must have shape (H, W) or (H, W, 3), got {a.shape}")
    # A str or bool scale reached numpy (a TypeError naming no parameter) or was written as 1.
    scale = check.positive("scale", scale)
    _write_pfm(path, a, scale, "array")


def _write_pfm(path: str | os.PathLike[str], a: np.ndarray, scale: float, name: str) -> None:
    """:func:`write_pfm` of a checked float array ``a``, after refusing a value beyond
    float32 (ValueError naming the parameter ``name``)."""
    if a.dtype.itemsize > 4:
        beyond = np.isfinite(a) & (np.abs(a) > np.finfo(np.float32).max)
        if beyond.any():
            where = tuple(int(i) for i in np.argwhere(beyond)[0])
            raise ValueError(
                f"{name} must fit in float32 (PFM stores float32; beyond, a value becomes an "
                f"infinity, read as unknown), got {float(a[where])!r} at row {where[0]}, "
                f"column {where[1]} ({int(beyond.sum())} such value"
                f"{'s' if beyond.sum() > 1 else ''})"
            )
    kind = "Pf" if a.ndim == 2 else "PF"
    height, width = a.shape[:2]
    header = f"{kind}\n{width} {height}\n{-float(scale)}\n".encode("ascii")
    body = np.ascontiguousarray(a[::-1], dtype="<f4")
    with atomic_write(path) as f:
        f.write(header)
        f.write(body.tobytes())


def write_disparity_pfm(path: str | os.PathLike[str], disparity: np.ndarray) -> None:
    """A float disparity map in Middlebury's format, atomically: a grey PFM (``Pf``, float32
    little-endian, scale -1, rows bottom to top, as :func:`write_pfm`) of the disparity in
    pixels, +infinity where there is none.

    The format (MiddEval3's README: "disparities ... in PFM format ... infinity for unknown
    values"; its ``evaldisp`` and ``computemask`` take only +infinity as invalid): a NaN hole,
    as stereodepth's matchers give, would be scored as a disparity, so every NaN is written as
    +infinity. A +infinity in ``disparity`` is already Middlebury's hole and is written as
    one (a ground truth read with :func:`read_pfm` is written back unchanged). Read back with
    :func:`read_disparity_pfm` (holes NaN), not :func:`read_pfm` (holes +infinity). Depth
    maps are not disparities: write them with :func:`write_pfm` (a depth of +infinity is
    disparity 0, a real value).

    ``disparity`` is a (H, W) float32 or float64 numpy array (float64 is stored as float32).

    Raises TypeError for anything else than such an array (a masked array: fill it first),
    ValueError for another shape, a -infinity (no disparity, and Middlebury would score it as
    one; the row and column of the first are named) or a finite value beyond float32's range
    (about 3.4e38), writing nothing; an OSError naming ``path`` when it cannot be written,
    ``path`` then left as it was."""
    d = _check_2d("disparity", disparity, (np.float32, np.float64))
    negative = np.isneginf(d)
    if negative.any():
        row, col = (int(i) for i in np.argwhere(negative)[0])
        count = int(negative.sum())
        raise ValueError(
            "disparity must not hold -inf (Middlebury's PFM has +inf for unknown; NaN or +inf "
            f"mark a hole), got -inf at row {row}, column {col} ({count} such value"
            f"{'s' if count > 1 else ''})"
        )
    _write_pfm(path, np.where(np.isnan(d), np.inf, d), 1.0, "disparity")


def read_disparity_pfm(path: str | os.PathLike[str]) -> np.ndarray:
    """A disparity map in Middlebury's format as (H, W) float32 pixels, NaN where there is
    none.

    The format (MiddEval3's ``disp0GT.pfm`` and submissions, also what
    :func:`write_disparity_pfm` writes): a grey PFM (``Pf``, read by :func:`read_pfm`, any
    byte order and scale) with +infinity for "unknown". Every value that is not finite gives
    NaN: +infinity (Middlebury's hole), NaN (a hole in stereodepth's disparity PFMs written
    with :func:`write_pfm`) and -infinity (no disparity either; scored as no value, as
    :func:`stereodepth.metrics.evaluate` scores any value that is not finite); every finite
    value is kept as stored.

    Raises FileNotFoundError for a missing file, IsADirectoryError for a folder, ValueError
    naming the file for a colour (``PF``) file, which holds no disparity map, and every error
    of :func:`read_pfm`."""
    p = _as_path(path)
    a = read_pfm(p)
    if a.ndim != 2:
        raise ValueError(
            f"{p}: a disparity PFM is a grey (Pf) map, got a colour (PF) PFM of shape {a.shape}"
        )
    a[~np.isfinite(a)] = np.nan
    return a


def read_pfm(path: str | os.PathLike[str]) -> np.ndarray:
    """A PFM file as float32 (H, W) or (H, W, 3), rows top to bottom, in native byte order.

    The format (Paul Debevec's, as Middlebury and netpbm write it): ``PF`` (colour) or ``Pf``
    (grey), the width and the height, the scale (its sign gives the byte order: negative
    little-endian, positive big-endian), separated by whitespace, then exactly
    width * height * channels float32 values, rows bottom to top. The header is parsed
    exactly: line breaks LF or CR LF, trailing spaces or tabs on a line; its last line must
    end with LF or CR LF, so that a data byte 0x0D or 0x0A right after it stays data, and
    the body must have exactly the size the header gives. PFM has no comments: a ``#`` in
    the header is refused.

    The header is parsed from the file's first bytes and the size it gives checked against
    the file's before the body is read: a file truncated or padded (to gigabytes) is refused
    at once, reading a few kB.

    Raises FileNotFoundError for a missing file, IsADirectoryError for a folder, ValueError
    naming the file and the fault: a bad magic, a non-numeric, zero or negative width or height, a
    non-numeric, zero or non-finite scale, a comment, a truncated body or extra bytes (how
    many), and MemoryError naming the file and its size when the array does not fit in
    memory (about twice the body's size is needed while the rows are turned)."""
    p = _as_path(path)
    require_file(p, "PFM file")
    with p.open("rb") as f:
        file_size = os.fstat(f.fileno()).st_size

        def parse(data: bytes, whole: bool) -> tuple[int, int, int, float, int, int]:
            if len(data) < 3 and not whole:
                raise _NeedMore
            if data[:2] not in (b"PF", b"Pf") or not data[2:3].isspace():
                if len(data) < 8 and not whole:  # the message shows 8 bytes
                    raise _NeedMore
                raise ValueError(
                    f"{p}: not a PFM file: it must start with 'PF' or 'Pf', got {data[:8]!r}"
                )
            channels = 3 if data[:2] == b"PF" else 1
            tokens, end = _header_tokens(p, data, 3, comments=False, what="PFM", whole=whole)
            width = _size(p, tokens[0], "width", "PFM")
            height = _size(p, tokens[1], "height", "PFM")
            if _FLOAT_RE.fullmatch(tokens[2]) is None:
                raise ValueError(f"{p}: PFM scale must be a number, got {tokens[2]!r}")
            scale = float(tokens[2])
            if scale == 0 or not np.isfinite(scale):
                raise ValueError(
                    f"{p}: bad PFM scale {tokens[2]!r}: it must be finite and not 0 (its sign "
                    "gives the byte order)"
                )
            count = width * height * channels
            desc = f"{width}x{height}x{channels} PFM"
            start = _body_start(p, data, whole, end, file_size, count * 4, desc)
            return width, height, channels, scale, count, start

        width, height, channels, scale, count, start = _parse_head(f, file_size, parse)
        desc = f"{width}x{height}x{channels} PFM"
        a = _read_body(p, f, start, np.dtype("<f4" if scale < 0 else ">f4"), count, desc)
    shape = (height, width) if channels == 1 else (height, width, 3)
    try:
        out: np.ndarray = a.reshape(shape)[::-1].astype(np.float32)  # native, top to bottom
        return out
    except MemoryError:
        raise MemoryError(
            f"{p}: not enough memory to read the {desc} ({count * 4} bytes of data, twice that "
            "while its rows are turned)"
        ) from None


# --- exact headers: PFM and PNM ---------------------------------------------------------------
_FLOAT_RE = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
#: What may lie between a header's last token and its data: spaces or tabs, then LF or CR LF.
#: No proper prefix of one of these is another, so a body one byte short is never read as a
#: header ending in a lone CR or space.
_HEADER_END_RE = re.compile(rb"[ \t]*\r?\n")
#: Between header tokens: whitespace and, where the format allows them, # comments to the end
#: of the line (CR or LF).
_SEP_RE = re.compile(rb"\s+")
_SEP_COMMENTS_RE = re.compile(rb"(?:\s|#[^\r\n]*)+")
_TOKEN_RE = re.compile(rb"[^\s#]+")


#: The first read of a PFM or PNM file, bytes: its header, however many spaces and comments it
#: holds, without reading the body (read only once the header's size has been checked against
#: the file's). A longer header is read in larger and larger parts.
_HEAD_BYTES = 1 << 16


class _NeedMore(Exception):
    """The part of a file read so far ends inside its header: read more of it."""


def _parse_head(f: IO[bytes], file_size: int, parse: Any) -> Any:
    """``parse(data, whole)`` on the first bytes of ``f``, more of them (4 times as many each
    time) while it raises :class:`_NeedMore`; ``whole`` says whether ``data`` is the whole
    file. The header is parsed without reading the body: a file padded to gigabytes is
    refused in a moment, not after reading it all."""
    n = _HEAD_BYTES
    while True:
        f.seek(0)
        data = f.read(n)
        whole = len(data) >= file_size or len(data) < n
        try:
            return parse(data, whole)
        except _NeedMore:
            if whole:  # pragma: no cover - parse raises _NeedMore only for a part
                raise
            n *= 4


def _header_tokens(
    p: Path, data: bytes, count: int, *, comments: bool, what: str, whole: bool = True
) -> tuple[list[str], int]:
    """The ``count`` header tokens after the 2-byte magic and the offset where the last ends.

    ``data`` is the file's first bytes, the whole file when ``whole``; otherwise
    :class:`_NeedMore` is raised where a token or a comment may go on past its end."""
    sep = _SEP_COMMENTS_RE if comments else _SEP_RE
    pos = 2
    tokens: list[str] = []
    for _ in range(count):
        m = sep.match(data, pos)
        if m is None:
            break
        pos = m.end()
        if not comments and data[pos : pos + 1] == b"#":
            raise ValueError(f"{p}: {what} headers have no comments, got a '#' at byte {pos}")
        t = _TOKEN_RE.match(data, pos)
        if t is None:
            break
        tokens.append(t.group().decode("latin-1"))
        pos = t.end()
    if not whole and (len(tokens) < count or pos >= len(data)):
        raise _NeedMore
    if len(tokens) < count:
        raise ValueError(
            f"{p}: incomplete {what} header: expected {count} fields after the magic, got "
            f"{len(tokens)} ({data[:40]!r})"
        )
    return tokens, pos


def _size(p: Path, token: str, name: str, what: str) -> int:
    if token.isdigit() and len(token.lstrip("0")) > 18:  # int() refuses 4300 digits
        raise ValueError(f"{p}: {what} {name} must be a whole number > 0, got {len(token)} digits")
    if not token.isdigit() or not token.isascii() or int(token) <= 0:
        raise ValueError(f"{p}: {what} {name} must be a whole number > 0, got {token!r}")
    return int(token)


def _body_start(
    p: Path, data: bytes, whole: bool, token_end: int, file_size: int, size: int, desc: str
) -> int:
    """Where the body of a binary PFM or PNM starts, after checking that the file holds one
    header line end after the header's last token (ending at ``token_end`` in ``data``, the
    file's first bytes) and then exactly ``size`` bytes: ValueError naming the file for a
    header without its line end, a truncated body or extra bytes, from the file's size
    (``file_size``) alone, before the body is read."""
    end = _HEADER_END_RE.match(data, token_end)
    if end is None and not whole:
        rest = data[token_end:]
        if len(rest) < 4 or re.fullmatch(rb"[ \t]*\r?", rest) is not None:
            raise _NeedMore  # the line end may lie beyond what was read
    if end is None and token_end < file_size:
        raise ValueError(
            f"{p}: {desc}: the header must end with one line break (LF or CR LF), got "
            f"{data[token_end : token_end + 4]!r}"
        )
    start = end.end() if end is not None else token_end
    avail = file_size - start
    if avail < size:
        raise ValueError(f"{p}: truncated {desc}: needs {size} bytes of data, got {avail}")
    if avail > size:
        raise ValueError(
            f"{p}: {desc} has {avail - size} bytes more than its header and {size} bytes of data"
        )
    return start


def _read_body(
    p: Path, f: IO[bytes], start: int, dtype: np.dtype, count: int, desc: str
) -> np.ndarray:
    """``count`` values of ``dtype`` read from ``f`` at byte ``start``, straight into a new
    array (no second copy as bytes); MemoryError naming the file when there is no room for
    it, ValueError when the file has shrunk since its size was checked."""
    size = count * dtype.itemsize
    try:
        out = np.empty(count, dtype)
    except MemoryError:
        raise MemoryError(
            f"{p}: not enough memory to read the {desc} ({size} bytes of data)"
        ) from None
    view = out.view(np.uint8).data  # a memoryview of its bytes
    f.seek(start)
    got = 0
    while got < size:
        n = f.readinto(view[got:])  # type: ignore[attr-defined]
        if not n:
            raise ValueError(f"{p}: truncated {desc}: needs {size} bytes of data, got {got}")
        got += n
    return out


#: PNM magic numbers: (name, samples per pixel, plain (ASCII) raster, has a maxval).
_PNM_KINDS = {
    b"P1": ("PBM", 1, True, False),
    b"P2": ("PGM", 1, True, True),
    b"P3": ("PPM", 3, True, True),
    b"P4": ("PBM", 1, False, False),
    b"P5": ("PGM", 1, False, True),
    b"P6": ("PPM", 3, False, True),
}


def _plain_raster(
    p: Path, data: bytes, end: int, name: str, has_maxval: bool, count: int, desc: str
) -> np.ndarray:
    """The samples of a plain (ASCII) PBM, PGM or PPM (P1 to P3) whose header ends at byte
    ``end`` of ``data``, the whole file: ``count`` of them, each checked."""
    rest = data[end:]
    if rest[:1] and not rest[:1].isspace():
        raise ValueError(f"{p}: {name} header must end with whitespace, got {rest[:8]!r}")
    if not has_maxval:  # P1: one character per pixel, whitespace anywhere
        raster = bytes(rest.translate(None, b" \t\r\n\v\f"))
        bad = raster.translate(None, b"01")
        if bad:
            raise ValueError(f"{p}: PBM samples must be 0 or 1, got {bad[:8]!r}")
        values: np.ndarray = np.frombuffer(raster, np.uint8) - ord("0")
    else:
        words = rest.split()
        if not all(w.isdigit() for w in words):
            first = next(w for w in words if not w.isdigit())
            raise ValueError(f"{p}: {name} samples must be whole numbers, got {first[:16]!r}")
        if len(words) != count:
            raise ValueError(f"{p}: {desc} needs {count} samples, got {len(words)}")
        if max(len(w.lstrip(b"0")) for w in words) > 5:  # keeps int64 from overflowing
            raise ValueError(f"{p}: {desc} has a sample above the maxval")
        values = np.array([int(w) for w in words], dtype=np.int64)
    if len(values) != count:
        raise ValueError(f"{p}: {desc} needs {count} samples, got {len(values)}")
    return values


def _pnm_head(p: Path, data: bytes, whole: bool, file_size: int) -> tuple[Any, ...]:
    """The header of the PNM file ``p`` (``file_size`` bytes) from its first bytes ``data``
    (the whole file when ``whole``; :class:`_NeedMore` where that is not enough): its kind,
    width, height, maxval, sample dtype, a description for messages, and where its raster
    starts (a binary body's size checked against the file's). ValueError naming the file for
    a malformed header."""
    if len(data) < 3 and not whole:
        raise _NeedMore
    kind = _PNM_KINDS.get(data[:2])
    if kind is None or not (data[2:3].isspace() or data[2:3] == b"#"):
        if len(data) < 8 and not whole:  # the message shows 8 bytes
            raise _NeedMore
        raise ValueError(
            f"{p}: not a PBM/PGM/PPM file: it must start with P1 to P6, got {data[:8]!r}"
        )
    name, samples, plain, has_maxval = kind
    tokens, end = _header_tokens(
        p, data, 3 if has_maxval else 2, comments=True, what=name, whole=whole
    )
    width = _size(p, tokens[0], "width", name)
    height = _size(p, tokens[1], "height", name)
    maxval = _size(p, tokens[2], "maxval", name) if has_maxval else 1
    if maxval > 65535:
        raise ValueError(f"{p}: {name} maxval must be at most 65535, got {maxval}")
    dtype = np.dtype(np.uint8 if maxval < 256 else np.uint16)
    desc = f"{width}x{height} {name}" + (f" with maxval {maxval}" if has_maxval else "")
    if plain:  # no exact size: read_pnm reads the raster whole
        return kind, width, height, maxval, dtype, desc, end
    # P4: rows of bits, each row padded to a whole byte; P5, P6: big-endian samples.
    size = (
        (width + 7) // 8 * height if not has_maxval else width * height * samples * dtype.itemsize
    )
    return (
        kind,
        width,
        height,
        maxval,
        dtype,
        desc,
        _body_start(p, data, whole, end, file_size, size, desc),
    )


def read_pnm(path: str | os.PathLike[str]) -> np.ndarray:
    """A netpbm PBM, PGM or PPM file (P1 to P6) as a numpy array, the samples as stored.

    PGM gives (H, W) and PPM (H, W, 3) RGB, uint8 when the maxval is below 256 and uint16
    otherwise (big-endian on disk), never rescaled to the maxval: a 12-bit image with maxval
    4095 reads as 0..4095, as ``cv2.imread(path, cv2.IMREAD_UNCHANGED)`` reads it (Pillow
    stretches it to 0..65535). PBM gives (H, W) uint8, 0 for black (1 in the file) and 255
    for white.

    The header follows the netpbm specification (netpbm.sourceforge.net/doc/pgm.html):
    whitespace-separated fields with ``#`` comments to the end of a line; line breaks LF or
    CR LF. The one deviation: a binary file's header must end with LF or CR LF (after
    optional spaces or tabs), not with a lone space or CR, so that a data byte 0x0D or 0x0A
    right after the header stays data and a body one byte short is refused rather than read
    shifted. The body must have exactly the size the header gives; a plain (ASCII) raster
    exactly width * height * samples values.

    A binary file's (P4 to P6) header is parsed from its first bytes and the size it gives
    checked against the file's before the body is read: a file truncated or padded (to
    gigabytes) is refused at once, reading a few kB. A plain (ASCII) raster has no exact size
    and is read whole.

    Raises FileNotFoundError for a missing file, IsADirectoryError for a folder, ValueError
    naming the file and the fault: a bad magic (PAM, P7, is not read), non-numeric, zero or negative
    width, height or maxval, a maxval above 65535, a sample above the maxval, a truncated body or
    extra bytes (how many), and MemoryError naming the file and its size when the image (or a
    plain file's text) does not fit in memory."""
    p = _as_path(path)
    require_file(p, "PNM file")
    with p.open("rb") as f:
        file_size = os.fstat(f.fileno()).st_size
        parse = functools.partial(_pnm_head, p, file_size=file_size)
        kind, width, height, maxval, dtype, desc, end = _parse_head(f, file_size, parse)
        name, samples, plain, has_maxval = kind
        count = width * height * samples
        shape = (height, width) if samples == 1 else (height, width, samples)
        if plain:
            try:
                f.seek(0)
                values = _plain_raster(p, f.read(), end, name, has_maxval, count, desc)
            except MemoryError:
                raise MemoryError(
                    f"{p}: not enough memory to read the plain (ASCII) {desc} ({file_size} bytes)"
                ) from None
        elif not has_maxval:  # P4
            row_bytes = (width + 7) // 8
            body = _read_body(p, f, end, np.dtype(np.uint8), row_bytes * height, desc)
            bits = np.unpackbits(body.reshape(height, row_bytes), axis=1)
            values = bits[:, :width]
        else:
            values = _read_body(p, f, end, dtype.newbyteorder(">"), count, desc)
    if not has_maxval:
        return np.ascontiguousarray(np.where(values.reshape(shape) == 1, 0, 255).astype(np.uint8))
    top = int(values.max())
    if top > maxval:
        raise ValueError(f"{p}: {desc} has a sample {top} above the maxval")
    return values.astype(dtype).reshape(shape)
