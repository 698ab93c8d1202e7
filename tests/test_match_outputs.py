"""``stereodepth match`` replaces the whole set of its files at --out: the outputs of an earlier
run that this one does not write are removed once the new set is complete, and only those:
the files the earlier run's record (a hidden file beside them) lists, unchanged since; never
another file, a file of the same name that match did not write or that was changed since, or
an input. A file at one of the run's own output names that the record does not list is the
user's: the run is refused unless --force. A run that fails, or cannot print its summary,
leaves the earlier set as it was."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("PIL", reason="reading images needs Pillow (the batch extra)")
pytest.importorskip("matplotlib", reason="the previews need the plot extra")

from PIL import Image

import stereodepth
from stereodepth.cli import main
from stereodepth.sample import sample_pair

#: Where this process imported stereodepth from (the source tree with an in-place build, or
#: site-packages after `pip install .`), for the child processes to import the same.
PYTHON_DIR = Path(stereodepth.__file__).resolve().parents[1]
RIG = ["--focal-px", "300", "--baseline-mm", "50", "--threads", "1"]


@pytest.fixture
def pair(tmp_path: Path) -> tuple[Path, Path]:
    s = sample_pair(96, 64)
    Image.fromarray(s.left).save(tmp_path / "l.png")
    Image.fromarray(s.right).save(tmp_path / "r.png")
    return tmp_path / "l.png", tmp_path / "r.png"


def run(capsys: pytest.CaptureFixture[str], *args: Any) -> tuple[int, str, str]:
    code = main(["match", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


MANIFEST = ".stereodepth-match.json"


def contents(folder: Path) -> dict[str, bytes]:
    """The files of ``folder`` but match's record of its last run."""
    return {
        p.name: p.read_bytes()
        for p in folder.iterdir()
        if p.is_file() and not p.name.endswith("stereodepth-match.json")
    }


def test_the_testers_three_runs_leave_one_set(
    pair: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Run 1 with a rig, previews and a cloud; run 2 with another search range, no previews,
    disparity as npy; run 3 without a rig: out/ held run 3's disparity beside run 2's depth
    and run 1's cloud and previews. Now each run leaves its own set only, lists what it
    removed, and leaves other files alone."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "depth.txt").write_text("not match's")
    code, _, err = run(capsys, *pair, *RIG, "--ply", "-o", f"{out}/")
    assert code == 0, err
    assert set(contents(out)) == {
        "notes.txt",
        "depth.txt",
        "disparity.pfm",
        "depth.npy",
        "disparity-preview.png",
        "depth-preview.png",
        "points.ply",
    }
    code, text, err = run(
        capsys,
        *pair,
        *RIG,
        "--num-disparities",
        "32",
        "--no-preview",
        "--disparity-format",
        "npy",
        "--json",
        "-o",
        f"{out}/",
    )
    assert code == 0, err
    assert set(contents(out)) == {"notes.txt", "depth.txt", "disparity.npy", "depth.npy"}
    removed = json.loads(text)["removed"]
    assert sorted(Path(p).name for p in removed) == sorted(
        ["disparity.pfm", "disparity-preview.png", "depth-preview.png", "points.ply"]
    )
    code, text, err = run(
        capsys, *pair, "--threads", "1", "--num-disparities", "16", "--no-preview", "-o", out
    )
    assert code == 0, err
    assert set(contents(out)) == {"notes.txt", "depth.txt", "disparity.pfm"}
    assert "removed" in text and "depth.npy" in text
    assert (out / "notes.txt").read_text() == "mine"


def test_a_prefix_owns_its_names_only(
    pair: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """With a prefix the set is the prefix's: another prefix's run in the same folder, and
    the folder's own disparity.pfm, stay; the prefix's earlier cloud goes."""
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "--ply", "-o", tmp_path / "b-")
    assert code == 0, err
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "--ply", "-o", tmp_path / "a-")
    assert code == 0, err
    (tmp_path / "disparity.pfm").write_bytes(b"the folder's")
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "-o", tmp_path / "a-")
    assert code == 0, err
    names = set(contents(tmp_path))
    assert {"a-disparity.pfm", "a-depth.npy", "b-depth.npy", "b-points.ply"} <= names
    assert "disparity.pfm" in names and "a-points.ply" not in names
    assert (tmp_path / "disparity.pfm").read_bytes() == b"the folder's"
    assert (tmp_path / ".a-stereodepth-match.json").is_file()
    assert (tmp_path / ".b-stereodepth-match.json").is_file()


def test_files_match_did_not_write_or_that_changed_since_stay(
    pair: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A points.ply of the user's in the folder (the default --out is '.'), and an earlier
    run's depth.npy edited since, are not match's to remove: a name alone is no proof."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "points.ply").write_bytes(b"the user's own cloud")
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "-o", out)
    assert code == 0, err
    assert (out / "points.ply").read_bytes() == b"the user's own cloud"
    (out / "depth.npy").write_bytes(b"edited")
    code, text, err = run(capsys, *pair, "--threads", "1", "--no-preview", "-o", out)
    assert code == 0, err
    assert (out / "depth.npy").read_bytes() == b"edited"
    assert (out / "points.ply").read_bytes() == b"the user's own cloud"
    assert "removed" not in text
    # Writing depth.npy and points.ply again would replace them: the record of the last run
    # (disparity.pfm only) does not list them, so that takes --force.
    before = contents(out)
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "--ply", "-o", out)
    assert code == 2 and err.count("\n") == 1, err
    assert "depth.npy is there and no earlier match run's record lists it" in err
    assert "--force" in err and contents(out) == before
    # Without its record nothing is removed, and a damaged record is no record.
    for record in (None, b"{not json", b'{"files": ["depth.npy"]}'):
        code, _, err = run(capsys, *pair, *RIG, "--no-preview", "--ply", "--force", "-o", out)
        assert code == 0, err
        if record is None:
            (out / MANIFEST).unlink()
        else:
            (out / MANIFEST).write_bytes(record)
        code, _, err = run(capsys, *pair, "--threads", "1", "--no-preview", "--force", "-o", out)
        assert code == 0, err
        assert (out / "points.ply").is_file() and (out / "depth.npy").is_file()


def test_a_file_of_the_users_at_an_output_name_is_refused_without_force(
    pair: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A depth.npy of the user's in the folder (the default --out is '.'), or one reached
    through a link, or at a prefix's name, was replaced without a word. Now the run is a
    usage error before any work (exit 2, one line naming --out and the file), which --force
    overrides; the files a run wrote, as its record lists them, are replaced freely."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "depth.npy").write_bytes(b"the user's depth")
    (tmp_path / "a-disparity.pfm").write_bytes(b"the prefix's namesake")
    for where, name in ((out, "depth.npy"), (tmp_path / "a-", "a-disparity.pfm")):
        before = contents(tmp_path)
        code, text, err = run(capsys, *pair, *RIG, "--no-preview", "-o", where)
        assert code == 2 and text == "" and err.count("\n") == 1, err
        assert err.startswith(f"stereodepth match: error: --out {where}: ")
        assert f"{name} is there and no earlier match run's record lists it" in err
        assert contents(tmp_path) == before and contents(out) == {"depth.npy": b"the user's depth"}
    # A link at an output name (to a file of the user's elsewhere) is refused as well.
    target = tmp_path / "elsewhere.pfm"
    target.write_bytes(b"the user's disparity")
    (out / "disparity.pfm").symlink_to(target)
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "-o", out)
    assert code == 2 and "disparity.pfm is there" in err, err
    assert target.read_bytes() == b"the user's disparity"
    # --force writes through the link (its target) and beside it; the next run needs no
    # --force, since its record lists both.
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "--force", "-o", out)
    assert code == 0, err
    assert (out / "disparity.pfm").is_symlink() and target.read_bytes()[:2] == b"Pf"
    assert (out / "depth.npy").read_bytes()[:6] == b"\x93NUMPY"
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "-o", out)
    assert code == 0, err
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "--force", "-o", tmp_path / "a-")
    assert code == 0, err
    assert (tmp_path / "a-disparity.pfm").read_bytes()[:2] == b"Pf"


def test_an_input_named_like_an_output_is_never_removed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The rectified pair of an earlier --write-rectified run, matched again from the same
    folder without --write-rectified: its names are match's, but they are this run's inputs."""
    s = sample_pair(96, 64)
    Image.fromarray(s.left).save(tmp_path / "left-rectified.png")
    Image.fromarray(s.right).save(tmp_path / "right-rectified.png")
    before = contents(tmp_path)
    code, _, err = run(
        capsys,
        tmp_path / "left-rectified.png",
        tmp_path / "right-rectified.png",
        "--no-preview",
        "--threads",
        "1",
        "-o",
        f"{tmp_path}/",
    )
    assert code == 0, err
    after = contents(tmp_path)
    assert {k: after[k] for k in before} == before


def test_a_failed_run_keeps_the_earlier_set_whole(
    pair: tuple[Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A write that fails after others (the cloud, after the disparity and depth) leaves the
    earlier set byte for byte (its disparity and depth were replaced or removed) and no
    temporary file."""
    out = tmp_path / "out"
    code, _, err = run(capsys, *pair, *RIG, "--ply", "-o", f"{out}/")
    assert code == 0, err
    before = contents(out)

    import stereodepth.pointcloud

    def disk_full(*args: Any, **kwargs: Any) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(stereodepth.pointcloud, "write_ply", disk_full)
    code, _, err = run(
        capsys, *pair, *RIG, "--num-disparities", "16", "--no-preview", "--ply", "-o", out
    )
    assert code == 1 and "No space left on device" in err and err.count("\n") == 1
    assert contents(out) == before
    assert sorted(p.name for p in out.iterdir()) == sorted([*before, MANIFEST])


def test_a_read_only_earlier_output_is_refused_before_any_work(
    pair: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An earlier run's file this run would remove, made read-only (kept on purpose), is
    refused as a read-only output is, a usage error naming --out (exit 2): nothing written,
    nothing removed."""
    out = tmp_path / "out"
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "--ply", "-o", f"{out}/")
    assert code == 0, err
    (out / "points.ply").chmod(0o444)
    before = contents(out)
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "-o", out)
    assert code == 2 and "read-only" in err and err.count("\n") == 1
    assert err.startswith(f"stereodepth match: error: --out {out}: cannot write points.ply")
    assert contents(out) == before
    assert sorted(p.name for p in out.iterdir()) == sorted([*before, MANIFEST])


def test_owned_names_are_every_name_match_writes() -> None:
    from stereodepth.match_command import OWNED_NAMES

    assert set(OWNED_NAMES) == {
        "disparity.pfm",
        "disparity.npy",
        "disparity.png",
        "depth.npy",
        "depth.pfm",
        "depth.png",
        "disparity-preview.png",
        "depth-preview.png",
        "points.ply",
        "left-rectified.png",
        "right-rectified.png",
    }


def command(tmp_path: Path, argv: list[str], stdout: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "stereodepth", *argv],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(PYTHON_DIR)},
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=True,
        timeout=300,
    )


def test_match_that_cannot_print_its_summary_fails_and_leaves_no_outputs(
    pair: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """stdout on /dev/full: the summary cannot be printed. The run used to exit 1 with every
    output written (of a failed run); now it fails before its outputs are put in place, and
    the earlier set stays as it was."""
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    out = tmp_path / "out"
    code, _, err = run(capsys, *pair, *RIG, "--ply", "-o", f"{out}/")
    assert code == 0, err
    before = contents(out)
    argv = ["match", "l.png", "r.png", *RIG, "--num-disparities", "16", "--no-preview"]
    for extra in ([], ["--json"]):
        with open("/dev/full", "w") as full:
            done = command(tmp_path, [*argv, *extra, "-o", "out"], full)
        assert done.returncode == 1
        assert done.stderr.startswith("stereodepth match: error: cannot print the summary")
        assert done.stderr.count("\n") == 1
        assert contents(out) == before
        assert sorted(p.name for p in out.iterdir()) == sorted([*before, MANIFEST])


def test_a_killed_runs_staged_files_are_removed_by_the_next_run(
    pair: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run killed outright (SIGKILL) leaves its staged files (hidden names with a random
    token); the next run at the same --out removes those of match's names, and nothing that
    only looks alike."""
    out = tmp_path / "out"
    out.mkdir()
    left_behind = [
        ".disparity.stereodepth-match-0123456789ab.pfm",
        ".points.stereodepth-match-abcdef012345.ply",
        ".depth-preview.stereodepth-match-00000000000f.png",
    ]
    alike = [
        ".notes.stereodepth-match-0123456789ab.txt",  # not a name match writes
        ".disparity.stereodepth-match-0123.pfm",  # not its token
        "disparity.stereodepth-match-0123456789ab.pfm",  # not hidden
        ".b-disparity.stereodepth-match-0123456789ab.pfm",  # another prefix's
    ]
    for name in left_behind + alike:
        (out / name).write_bytes(b"x")
    code, _, err = run(capsys, *pair, *RIG, "--no-preview", "-o", out)
    assert code == 0, err
    names = set(contents(out))
    assert not names & set(left_behind)
    assert set(alike) <= names
