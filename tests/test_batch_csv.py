"""The CSV list of stereodepth batch is parsed exactly: UTF-8 with or without a byte-order
mark, LF or CR LF, cells stripped, trailing empty cells ignored, ``#`` comments and blank lines
skipped, an optional header first; anything else raises a ValueError naming file and line."""

from __future__ import annotations

from pathlib import Path

import pytest

from stereodepth import batch


def write(tmp_path: Path, text: str, *, newline: str = "\n", bom: bool = False) -> Path:
    p = tmp_path / "pairs.csv"
    p.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.replace("\n", newline).encode())
    return p


LIST = (
    "left,right,stem\n"
    "# a comment line\n"
    "\n"
    "  imgs/a_left.png , imgs/a_right.png ,  \n"
    'imgs/b0.png,"imgs/b 1.png",frame-b,,\n'
    "   \n"
)


@pytest.mark.parametrize("newline", ["\n", "\r\n"], ids=["LF", "CRLF"])
@pytest.mark.parametrize("bom", [False, True], ids=["plain", "bom"])
def test_a_list_parses_the_same_whatever_its_line_ends(
    tmp_path: Path, newline: str, bom: bool
) -> None:
    pairs = batch.find_pairs(write(tmp_path, LIST, newline=newline, bom=bom))
    assert [(p.stem, p.left, p.right) for p in pairs] == [
        ("a", tmp_path / "imgs/a_left.png", tmp_path / "imgs/a_right.png"),
        ("frame-b", tmp_path / "imgs/b0.png", tmp_path / "imgs/b 1.png"),
    ]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("a.png,b.png\nc.png\n", r"pairs.csv:2: expected left,right\[,stem\], got 'c.png'"),
        ("a.png,b.png,s,extra\n", r"pairs.csv:1: expected left,right\[,stem\]"),
        ("a.png,,s\n", r"pairs.csv:1: expected left,right\[,stem\]"),
        ("x/a.png,x/./a.png\n", r"pairs.csv:1: the left and right image are the same file"),
        ("a.png,b.png\nleft,right\n", r"pairs.csv:2: a header line after the first pair"),
        ('a.png,"b.png\n', r"pairs.csv:1: not a valid CSV line"),
    ],
    ids=["short", "long", "empty-right", "same-file", "late-header", "open-quote"],
)
def test_bad_lines_are_refused_with_file_and_line(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        batch.find_pairs(write(tmp_path, text))


def test_a_link_to_the_left_image_is_the_same_file(tmp_path: Path) -> None:
    # Only the spelled paths were compared: a symbolic or hard link to the left image was
    # matched against it (disparity 0 everywhere), as `stereodepth match` did with any pair.
    (tmp_path / "a.png").write_bytes(b"an image")
    (tmp_path / "soft.png").symlink_to(tmp_path / "a.png")
    (tmp_path / "hard.png").hardlink_to(tmp_path / "a.png")
    for other in ("soft.png", "hard.png"):
        with pytest.raises(ValueError, match=r"pairs.csv:1: the left and right image are the same"):
            batch.find_pairs(write(tmp_path, f"a.png,{other}\n"))


def test_a_file_that_is_not_utf8_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "pairs.csv"
    p.write_bytes(b"caf\xe9.png,b.png\n")
    with pytest.raises(ValueError, match=r"pairs.csv: not UTF-8 text"):
        batch.find_pairs(p)


def test_a_quoted_cell_after_a_space_is_unquoted(tmp_path: Path) -> None:
    # 'a.png, "b 1.png"' (a space after the comma, as lists are written by hand) kept the
    # quotes as part of the path: the pair failed later with a missing '"b 1.png"'.
    pairs = batch.find_pairs(write(tmp_path, 'imgs/a0.png,  "imgs/a 1.png", "frame, a"\n'))
    assert [(p.stem, p.left, p.right) for p in pairs] == [
        ("frame, a", tmp_path / "imgs/a0.png", tmp_path / "imgs/a 1.png")
    ]


def test_text_after_a_closing_quote_is_refused_with_file_and_line(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"pairs.csv:2: not a valid CSV line"):
        batch.find_pairs(write(tmp_path, 'a.png,b.png\nc.png,"d.png" ,s\n'))


@pytest.mark.parametrize("text", ["", "left,right,stem\n", "# nothing yet\n\n"])
def test_a_list_without_pairs_is_called_a_list(tmp_path: Path, text: str) -> None:
    # It was "no stereo pairs found in pairs.csv (searched 3 levels of folders): expected
    # image_2/image_3 ... or a CSV list", about folders, for a CSV list.
    with pytest.raises(
        ValueError, match=r"^no stereo pairs in the CSV list .*pairs.csv: it has no left,right line"
    ):
        batch.find_pairs(write(tmp_path, text))
