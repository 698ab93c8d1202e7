"""Finding the stereo pairs of a folder or a CSV list (see :mod:`stereodepth.batch`)."""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

from .job import Pair, UsageError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".pnm", ".bmp", ".tif", ".tiff", ".webp")
#: Left/right sub-folders, in the order they are tried, with their KITTI camera numbers.
FOLDER_PAIRS: tuple[tuple[str, str, tuple[int, int] | None], ...] = (
    ("image_2", "image_3", (2, 3)),
    ("image_0", "image_1", (0, 1)),
    ("left", "right", None),
)
#: Tokens that name the left and right image of a pair, in the order they are tried.
PAIR_NAMES: tuple[tuple[str, str], ...] = (
    ("im0", "im1"),
    ("left", "right"),
    ("Left", "Right"),
    ("LEFT", "RIGHT"),
)


def _is_image(p: Path) -> bool:
    return p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")


def _safe_stem(text: str) -> str:
    stem = re.sub(r"[\\/\x00-\x1f]+", "_", text).strip(" .")
    return stem or "pair"


def _token_split(stem: str, names: Sequence[tuple[str, str]]) -> tuple[str, str, str] | None:
    """(left token, right token, the stem without the token) for a left image's stem."""
    for left_tok, right_tok in names:
        i = stem.rfind(left_tok)
        if i >= 0:
            rest = stem[:i].rstrip("_-. ") + "_" + stem[i + len(left_tok) :].lstrip("_-. ")
            return left_tok, right_tok, rest.strip("_")
    return None


def _scene_pairs(d: Path, names: Sequence[tuple[str, str]], *, prefix: str | None) -> list[Pair]:
    pairs = []
    files = sorted(p for p in d.iterdir() if p.is_file() and _is_image(p))
    for f in files:
        split = _token_split(f.stem, names)
        if split is None:
            continue
        left_tok, right_tok, rest = split
        i = f.stem.rfind(left_tok)
        right_name = f.stem[:i] + right_tok + f.stem[i + len(left_tok) :] + f.suffix
        stem = (rest or d.name) if prefix is None else (f"{prefix}_{rest}" if rest else prefix)
        calib = d / "calib.txt"
        pairs.append(
            Pair(
                stem=_safe_stem(stem),
                left=f,
                right=d / right_name,
                calib_file=calib if calib.is_file() else None,
            )
        )
    return pairs


def _kitti_calib_for(root: Path, stem: str) -> Path | None:
    frame = re.sub(r"_\d\d$", "", stem)
    for sub in ("calib", "calib_cam_to_cam"):
        p = root / sub / f"{frame}.txt"
        if p.is_file():
            return p
    return None


def _folder_pairs(root: Path) -> list[Pair] | None:
    for left_dir, right_dir, cams in FOLDER_PAIRS:
        ld, rd = root / left_dir, root / right_dir
        if not (ld.is_dir() and rd.is_dir()):
            continue
        pairs = []
        shared_calib = root / "calib.txt"
        for f in sorted(p for p in ld.iterdir() if p.is_file() and _is_image(p)):
            calib = _kitti_calib_for(root, f.stem) if cams else None
            kitti = cams if calib is not None else None
            if calib is None and shared_calib.is_file():
                calib = shared_calib
            pairs.append(
                Pair(
                    stem=_safe_stem(f.stem),
                    left=f,
                    right=rd / f.name,
                    calib_file=calib,
                    kitti_cams=kitti,
                )
            )
        return pairs
    return None


def _csv_pairs(path: Path, names: Sequence[tuple[str, str]]) -> list[Pair]:
    import csv

    pairs = []
    first = True
    with path.open(newline="", encoding="utf-8") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            cells = [c.strip() for c in row]
            if not cells or not any(cells) or cells[0].startswith("#"):
                continue
            if first and cells[0].lower() == "left":
                first = False
                continue  # header
            first = False
            if len(cells) not in (2, 3) or not cells[0] or not cells[1]:
                raise UsageError(
                    f"{path}:{lineno}: expected left,right[,stem], got {','.join(row)!r}"
                )
            left = (path.parent / cells[0]) if not Path(cells[0]).is_absolute() else Path(cells[0])
            right = (path.parent / cells[1]) if not Path(cells[1]).is_absolute() else Path(cells[1])
            if len(cells) == 3 and cells[2]:
                stem = cells[2]
            else:
                split = _token_split(left.stem, names)
                stem = (split[2] if split else left.stem) or left.parent.name
            calib = left.parent / "calib.txt"
            pairs.append(
                Pair(
                    stem=_safe_stem(stem),
                    left=left,
                    right=right,
                    calib_file=calib if calib.is_file() else None,
                )
            )
    return pairs


def find_pairs(
    input_path: str | os.PathLike[str],
    *,
    pair_names: Sequence[tuple[str, str]] | None = None,
) -> list[Pair]:
    """The stereo pairs of a folder or a CSV list (see the module's documentation), in order.

    Pairs whose right image is missing are returned too (they fail when processed, and the
    report names them). Raises UsageError when nothing is found or two pairs would write the
    same outputs."""
    root = Path(input_path)
    names = list(pair_names) if pair_names else list(PAIR_NAMES)
    if not root.exists():
        raise UsageError(f"INPUT not found: {root}")
    if root.is_file():
        if root.suffix.lower() != ".csv":
            raise UsageError(f"INPUT must be a folder or a .csv list of pairs, got {root}")
        pairs = _csv_pairs(root, names)
    else:
        found = _folder_pairs(root)
        if found is None:
            found = _scene_pairs(root, names, prefix=None)
            for sub in sorted(p for p in root.iterdir() if p.is_dir()):
                if not sub.name.startswith("."):
                    found += _scene_pairs(sub, names, prefix=sub.name)
        pairs = found
    if not pairs:
        tokens = ", ".join(f"{a}/{b}" for a, b in names)
        raise UsageError(
            f"no stereo pairs found in {root}: expected image_2/image_3 (or image_0/image_1, "
            f"left/right) folders, scene folders with pairs named {tokens}, or a CSV list"
        )
    seen: dict[str, Pair] = {}
    for p in pairs:
        if p.stem in seen:
            raise UsageError(
                f"two pairs would write the same outputs {p.stem!r}: {seen[p.stem].left} and "
                f"{p.left} (give output stems in a CSV list)"
            )
        seen[p.stem] = p
    return pairs
