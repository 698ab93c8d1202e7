"""Finding the stereo pairs of a folder or a CSV list (see :mod:`stereodepth.batch`).

A folder is searched down to :data:`SEARCH_DEPTH` levels below INPUT; what is not used is
listed with the reason (:attr:`Discovery.skipped`), so that no pair goes missing silently.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
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
#: How many levels of folders below INPUT are searched for pairs (INPUT itself is level 0).
SEARCH_DEPTH = 3


@dataclass(frozen=True)
class Discovery:
    """What :func:`discover` found: the pairs in order, and ``skipped``, the folders that hold
    images but gave no pair or were not searched, each with the reason."""

    pairs: list[Pair]
    skipped: list[tuple[Path, str]] = field(default_factory=list)

    def skipped_text(self, limit: int = 5) -> list[str]:
        """One line per skipped folder (at most ``limit``, then how many more)."""
        lines = [f"skipped {path}: {why}" for path, why in self.skipped[:limit]]
        if len(self.skipped) > limit:
            lines.append(f"... and {len(self.skipped) - limit} more folders skipped")
        return lines


def check_pair_names(names: Sequence[tuple[str, str]], what: str = "pair_names") -> None:
    """Raises UsageError unless each (left, right) is two different non-empty tokens, neither
    part of the other (else a right image would be taken for a left one, or for itself), with
    no path separator."""
    for left, right in names:
        if not (isinstance(left, str) and isinstance(right, str)) or not left or not right:
            raise UsageError(f"{what}: two non-empty names are needed, got {left!r} and {right!r}")
        for tok in (left, right):
            if "/" in tok or "\\" in tok:
                raise UsageError(f"{what}: a name cannot hold a path separator, got {tok!r}")
        if left == right:
            raise UsageError(
                f"{what}: the left and right names must differ, got {left!r} twice "
                "(each image would be paired with itself)"
            )
        if left in right or right in left:
            raise UsageError(
                f"{what}: neither name may be part of the other, got {left!r} and {right!r} "
                "(a right image would also be taken for a left one)"
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


def _images(d: Path) -> list[Path]:
    try:
        return sorted(p for p in d.iterdir() if p.is_file() and _is_image(p))
    except OSError:
        return []


def _subfolders(d: Path) -> list[Path]:
    try:
        return sorted(p for p in d.iterdir() if p.is_dir() and not p.name.startswith("."))
    except OSError:
        return []


def _batch_outputs(d: Path) -> set[str]:
    """The names of the files in ``d`` that an earlier batch job wrote there, as its pairs'
    records (``*.record.json``) list them: a job's OUTDIR inside INPUT holds images such as
    ``S.left-rectified.png`` and ``S.right-rectified.png``, which are outputs, not pairs."""
    from .job import RECORD_SUFFIX, read_record

    names: set[str] = set()
    try:
        records = [p for p in d.iterdir() if p.name.endswith(RECORD_SUFFIX) and p.is_file()]
    except OSError:
        return names
    for p in records:
        record = read_record(p)
        if record is None:
            continue  # not a record of ours: its folder is searched as usual
        try:
            outputs = record.get("outputs") or {}
            names.update(Path(o["path"]).name for o in outputs.values())
        except (OSError, ValueError, TypeError, AttributeError, KeyError):
            continue  # not a record of ours: its folder is searched as usual
    return names


def _whole_token_at(stem: str, token: str) -> int:
    """Where ``token`` last stands in ``stem`` as a whole word (no letter or digit either side:
    x_im1, 0003_right, im1), or -1 (im1E, im10, copyright)."""
    i = stem.rfind(token)
    while i >= 0:
        before = stem[i - 1] if i > 0 else ""
        after = stem[i + len(token)] if i + len(token) < len(stem) else ""
        if not before.isalnum() and not after.isalnum():
            return i
        i = stem.rfind(token, 0, i + len(token) - 1)
    return -1


def _rights_alone(
    d: Path, names: Sequence[tuple[str, str]], pairs: Sequence[Pair]
) -> list[tuple[str, str]]:
    """(name, the left image's name it lacks) for each image in ``d`` named with a right
    token as a whole word (x_im1.png, 0003_right.png; not im1E.png, Middlebury 2014's other
    exposure, nor copyright.png) that is the right image of none of ``pairs``."""
    used = {p.right.name for p in pairs}
    outputs = _batch_outputs(d)
    alone = []
    for f in _images(d):
        if f.name in used or f.name in outputs or _token_split(f.stem, names) is not None:
            continue
        for left_tok, right_tok in names:
            i = _whole_token_at(f.stem, right_tok)
            if i >= 0:
                left = f.stem[:i] + left_tok + f.stem[i + len(right_tok) :] + f.suffix
                alone.append((f.name, left))
                break
    return alone


def _scene_pairs(d: Path, names: Sequence[tuple[str, str]], *, prefix: str | None) -> list[Pair]:
    pairs = []
    outputs = _batch_outputs(d)
    for f in _images(d):
        if f.name in outputs:
            continue
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
    """The KITTI layout's calibration file of a frame: ``calib/<frame>.txt`` (2012) or
    ``calib_cam_to_cam/<frame>.txt`` (2015), the frame being the image name without its
    ``_10``/``_11`` suffix. Locating the file only; :func:`stereodepth.calib.read_kitti_calib`
    reads it."""
    frame = re.sub(r"_\d\d$", "", stem)
    for sub in ("calib", "calib_cam_to_cam"):
        p = root / sub / f"{frame}.txt"
        if p.is_file():
            return p
    return None


def _folder_pairs(
    root: Path, *, prefix: str | None
) -> tuple[list[Pair], list[tuple[Path, str]], tuple[str, str]] | None:
    """The pairs of a folder holding left and right sub-folders (KITTI's ``image_2`` and
    ``image_3``...) and the right sub-folder's images that have no left image of their name
    (skipped, with the reason), or None when it holds no such sub-folders."""
    for left_dir, right_dir, cams in FOLDER_PAIRS:
        ld, rd = root / left_dir, root / right_dir
        if not (ld.is_dir() and rd.is_dir()):
            continue
        pairs = []
        shared_calib = root / "calib.txt"
        lefts = _images(ld)
        names = {f.name for f in lefts}
        alone = [f.name for f in _images(rd) if f.name not in names]
        skipped = [
            # Only the first layout is used: KITTI's grey pair beside its colour pair went
            # missing silently (their frames share names, so both would write one stem).
            (
                root / other_left,
                f"{other_left}/{other_right} beside {left_dir}/{right_dir}, which are used "
                "(a CSV list names the others' pairs)",
            )
            for other_left, other_right, _ in FOLDER_PAIRS
            if other_left != left_dir
            and (root / other_left).is_dir()
            and (root / other_right).is_dir()
            and _images(root / other_left)
        ]
        if alone:
            # A right image whose left one is missing or named otherwise (0001.jpg beside
            # 0001.png) went missing silently.
            shown = ", ".join(alone[:3]) + (f" and {len(alone) - 3} more" if len(alone) > 3 else "")
            skipped.append(
                (
                    rd,
                    f"{len(alone)} image{'s' if len(alone) != 1 else ''} with no left image of "
                    f"the same name in {left_dir} ({shown})",
                )
            )
        if not lefts and _subfolders(ld):  # left/seq1/0001.png: "no pairs", and no reason
            skipped.append((ld, "no images in it, only folders (which are not searched)"))
        for f in lefts:
            calib = _kitti_calib_for(root, f.stem) if cams else None
            if calib is None and shared_calib.is_file():
                calib = shared_calib  # KITTI odometry's sequences/NN/calib.txt, for example
            pairs.append(
                Pair(
                    stem=_safe_stem(f.stem if prefix is None else f"{prefix}_{f.stem}"),
                    left=f,
                    right=rd / f.name,
                    calib_file=calib,
                    # The folders' cameras, for whichever KITTI file calibrates them (their
                    # own, a shared calib.txt, --calib): the grey pair image_0/image_1 once got
                    # the colour pair's P2/P3 baseline from all but the first.
                    kitti_cams=cams,
                )
            )
        return pairs, skipped, (left_dir, right_dir)
    return None


def _search(
    root: Path, names: Sequence[tuple[str, str]], exclude: Sequence[Path]
) -> tuple[list[Pair], list[tuple[Path, str]]]:
    """Walks ``root`` down to SEARCH_DEPTH levels: a folder with left/right sub-folders is one
    set of pairs (its sub-folders are its own), any other folder gives the pairs named by
    tokens in it, then its sub-folders are searched. Hidden folders and ``exclude`` (OUTDIR)
    are left out."""
    tokens = ", ".join(f"{a}/{b}" for a, b in names)
    excluded = {p.resolve() for p in exclude}
    pairs: list[Pair] = []
    skipped: list[tuple[Path, str]] = []
    # Each folder is searched once: a link to a folder searched already (``d/loop -> ..``)
    # matched its pairs again under other stems.
    searched: dict[Path, Path] = {root.resolve(): root}

    def visit(d: Path, rel: tuple[str, ...]) -> None:
        # A folder that cannot be read (no permission: Path.is_dir raises for what is inside
        # it) is listed with the reason and skipped, where it ended the whole job.
        try:
            search(d, rel)
        except OSError as exc:
            skipped.append((d, f"cannot be searched: {exc.strerror or exc}"))

    def search(d: Path, rel: tuple[str, ...]) -> None:
        prefix = "_".join(rel) if rel else None
        layout = _folder_pairs(d, prefix=prefix)
        if layout is not None:
            pairs.extend(layout[0])
            skipped.extend(layout[1])
            # Its other sub-folders are not searched: one holding images (a scene beside
            # left/right) went missing silently.
            left_dir, right_dir = layout[2]
            noted = {path for path, _ in skipped}
            noted |= {d / r for left, r, _ in FOLDER_PAIRS if d / left in noted}  # image_1 too
            for sub in _subfolders(d):
                if sub.name in (left_dir, right_dir) or sub in noted:
                    continue
                if sub.resolve() in excluded or not _images(sub) or _batch_outputs(sub):
                    continue
                why = f"not searched: beside {left_dir}/{right_dir} (a CSV list names its pairs)"
                skipped.append((sub, why))
            return
        found = _scene_pairs(d, names, prefix=prefix)
        pairs.extend(found)
        if found:
            # A right image whose left one is missing or named otherwise (x_im1.png beside
            # im0.png and im1.png) went missing silently, where a left one without its right
            # is a failed pair; as in left/right folders, such images are listed.
            for name, left_name in _rights_alone(d, names, found):
                skipped.append((d / name, f"a right image with no left image {left_name}"))
        if not found:
            images = _images(d)
            ours = _batch_outputs(d)
            n = sum(1 for f in images if f.name not in ours)
            if len(images) > n:
                skipped.append(
                    (d, "the outputs of an earlier batch job (its *.record.json list them)")
                )
            if n:
                skipped.append(
                    (
                        d,
                        f"{n} image{'s' if n != 1 else ''} but no pair (no left image named "
                        f"with {tokens}; --pair-names LEFT RIGHT names others)",
                    )
                )
        for sub in _subfolders(d):
            real = sub.resolve()
            if real in excluded:
                if _images(sub):
                    skipped.append((sub, "the output folder (-o): not searched"))
                continue
            if real in searched:
                skipped.append(
                    (sub, f"the same folder as {searched[real]} (a link): not searched again")
                )
                continue
            if len(rel) >= SEARCH_DEPTH:
                if _images(sub) or _subfolders(sub):
                    skipped.append(
                        (sub, f"not searched: more than {SEARCH_DEPTH} levels below INPUT")
                    )
                continue
            searched[real] = sub
            visit(sub, (*rel, sub.name))

    visit(root, ())
    return pairs, skipped


def folder_cameras(left: Path, right: Path) -> tuple[int, int] | None:
    """The KITTI cameras of a pair by its images' folders (``image_0``/``image_1``: (0, 1),
    ``image_2``/``image_3``: (2, 3)), None for other folders: those a KITTI file is read for."""
    # absolute: "000000.png" run from inside image_0 has the folder "" as given
    folders = (Path(os.path.abspath(left)).parent.name, Path(os.path.abspath(right)).parent.name)
    for left_dir, right_dir, cams in FOLDER_PAIRS:
        if cams is not None and folders == (left_dir, right_dir):
            return cams
    return None


def _csv_path(base: Path, cell: str) -> Path:
    p = Path(cell)
    return p if p.is_absolute() else base / p


def _same_file(a: Path, b: Path) -> bool:
    """Whether two existing paths are one file (a symbolic or hard link); False when either
    is missing (that pair fails on its own)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _csv_pairs(path: Path, names: Sequence[tuple[str, str]]) -> list[Pair]:
    """The pairs of a CSV list, parsed exactly: UTF-8 (a byte-order mark is allowed), LF or
    CR LF line ends, cells stripped of surrounding spaces (a quoted cell may follow spaces,
    ``a.png, "b 1.png"``; text after its closing quote is refused), empty trailing cells ignored;
    blank lines and lines whose first cell starts with ``#`` are skipped; an optional header
    ``left,right[,stem]`` first. Anything else raises UsageError (a ValueError) naming the
    file, the line and what was wrong."""
    import csv

    pairs = []
    header_allowed = True
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            # skipinitialspace: a quote after spaces opens a quoted cell (else the quotes were
            # kept as part of the path, and the pair failed later as a missing file).
            reader = csv.reader(fh, strict=True, skipinitialspace=True)
            for row in reader:
                where = f"{path}:{reader.line_num}"
                cells = [c.strip() for c in row]
                while cells and not cells[-1]:
                    cells.pop()
                if not cells or cells[0].startswith("#"):
                    continue
                is_header = [c.lower() for c in cells[:2]] == ["left", "right"] and (
                    len(cells) == 2 or (len(cells) == 3 and cells[2].lower() == "stem")
                )
                if is_header:
                    if not header_allowed:
                        raise UsageError(f"{where}: a header line after the first pair")
                    header_allowed = False
                    continue
                header_allowed = False
                if len(cells) not in (2, 3) or not cells[0] or not cells[1]:
                    raise UsageError(f"{where}: expected left,right[,stem], got {','.join(row)!r}")
                left, right = _csv_path(path.parent, cells[0]), _csv_path(path.parent, cells[1])
                if os.path.normpath(left) == os.path.normpath(right) or _same_file(left, right):
                    raise UsageError(f"{where}: the left and right image are the same file {left}")
                if len(cells) == 3:
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
                        kitti_cams=folder_cameras(left, right),  # for a KITTI --calib
                    )
                )
    except csv.Error as exc:
        raise UsageError(f"{path}:{reader.line_num}: not a valid CSV line: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise UsageError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror or exc}") from exc
    return pairs


def _without_outputs(
    pairs: list[Pair], out_dirs: Sequence[Path]
) -> tuple[list[Pair], list[tuple[Path, str]]]:
    """The pairs found, without those whose left image is an output of another pair found, in
    OUTDIR (``out_dirs``), and those left out, with the reason.

    OUTDIR is searched when it is INPUT itself or a folder of left images (outputs beside the
    inputs). A scene folder's images that a pair's record lists are not taken for pairs, but
    a job killed mid-pair (SIGKILL, the OOM killer, a power cut) leaves the images it wrote
    without a record, and left/right folders (KITTI's image_2) have no such check: then
    ``p0.left-rectified.png`` and ``p0.right-rectified.png``, or ``000000_10.depth.png`` of
    ``--format png16`` in ``image_2``, were found as new pairs, and since pair ``p0`` or
    ``000000_10`` writes them, the next run was refused ('which is the input ...: choose
    another OUTDIR'), so the job could not be resumed."""
    from .job import owned_names

    if not out_dirs:
        return pairs, []
    owner: dict[Path, str] = {}
    for d in out_dirs:
        folder = d.resolve()
        for p in pairs:
            for name in owned_names(p.stem):
                owner.setdefault(folder / name, p.stem)
    kept: list[Pair] = []
    left_out: list[tuple[Path, str]] = []
    for p in pairs:
        # where the image's name is (a link there is written through by that pair too)
        stem = owner.get(p.left.parent.resolve() / p.left.name)
        if stem is None or stem == p.stem:
            kept.append(p)
            continue
        left_out.append(
            (
                p.left,
                f"an output of pair {stem!r} in OUTDIR, not a pair",
            )
        )
    return kept, left_out


def discover(
    input_path: str | os.PathLike[str],
    *,
    pair_names: Sequence[tuple[str, str]] | None = None,
    exclude: Sequence[str | os.PathLike[str]] = (),
) -> Discovery:
    """The stereo pairs of a folder or a CSV list (see :mod:`stereodepth.batch`), in order,
    and the folders skipped with the reason. ``exclude``: folders not to search (OUTDIR).

    Pairs whose right image is missing are returned too (they fail when processed, and the
    report names them). Raises UsageError when nothing is found (naming what was skipped),
    for a pair whose left and right image are one file (a link),
    when two pairs would write the same outputs (stems equal but for case included: they
    collide on case-insensitive file systems), or for bad ``pair_names``."""
    root = Path(input_path)
    names = list(pair_names) if pair_names else list(PAIR_NAMES)
    check_pair_names(names)
    skipped: list[tuple[Path, str]] = []
    if not root.exists():
        raise UsageError(f"INPUT not found: {root}")
    if not root.is_file() and not root.is_dir():  # a pipe was "searched" as a folder
        raise UsageError(
            f"INPUT must be a folder or a .csv list of pairs, got {root} (not a regular file: "
            "a device, pipe or socket)"
        )
    if root.is_file():
        if root.suffix.lower() != ".csv":
            raise UsageError(f"INPUT must be a folder or a .csv list of pairs, got {root}")
        pairs = _csv_pairs(root, names)
    else:
        pairs, skipped = _search(root, names, [Path(p) for p in exclude])
        pairs, unrecorded = _without_outputs(pairs, [Path(p) for p in exclude])
        skipped.extend(unrecorded)
        for p in pairs:
            # A link (image_3/x.png linked to image_2/x.png, --pair-names naming a link to
            # the left image) matched the image with itself: every disparity 0, "ok". The
            # rule of a CSV list's line.
            if _same_file(p.left, p.right):
                raise UsageError(
                    f"pair {p.stem!r}: the left and right image are the same file ({p.left} "
                    f"and {p.right})"
                )
    found = Discovery(pairs, skipped)
    if not pairs and root.is_file():  # not "searched 3 levels of folders ... or a CSV list"
        raise UsageError(
            f"no stereo pairs in the CSV list {root}: it has no left,right line (only a "
            "header, comments or blank lines)"
        )
    if not pairs:
        tokens = ", ".join(f"{a}/{b}" for a, b in names)
        why = "; ".join(found.skipped_text(3))
        raise UsageError(
            f"no stereo pairs found in {root} (searched {SEARCH_DEPTH} levels of folders): "
            f"expected image_2/image_3 (or image_0/image_1, left/right) folders, scene folders "
            f"with pairs named {tokens}, or a CSV list" + (f"; {why}" if why else "")
        )
    seen: dict[str, Pair] = {}
    for p in pairs:
        key = p.stem.casefold()
        if key in seen:
            raise UsageError(
                f"two pairs would write the same outputs {p.stem!r}: {seen[key].left} and "
                f"{p.left} (give output stems in a CSV list)"
            )
        seen[key] = p
    return found


def find_pairs(
    input_path: str | os.PathLike[str],
    *,
    pair_names: Sequence[tuple[str, str]] | None = None,
    exclude: Sequence[str | os.PathLike[str]] = (),
) -> list[Pair]:
    """The pairs of :func:`discover` (the same arguments and errors)."""
    return discover(input_path, pair_names=pair_names, exclude=exclude).pairs
