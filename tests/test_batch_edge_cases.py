"""stereodepth batch as a new user meets it: where the outputs go, which pairs are found,
what a failed re-run leaves, which calibration wins, what is checked before the first pair,
colour and grey, the lock file, the colour order (issue 10, items 4 and 5)."""

from __future__ import annotations

import inspect
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ply_files import read_ply

import stereodepth
from stereodepth import batch, cli

Image = pytest.importorskip("PIL.Image")

SHAPE = (32, 48)


def save_pair(
    d: Path, left_name: str, right_name: str, *, seed: int = 0, rgb: bool = False
) -> None:
    d.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    left = rng.integers(0, 256, (*SHAPE, 3) if rgb else SHAPE, dtype=np.uint8)
    Image.fromarray(left).save(d / left_name)
    Image.fromarray(np.roll(left, -3, axis=1)).save(d / right_name)


def calib_txt(ndisp: int | None = 16) -> str:
    text = (
        "cam0=[700 0 24; 0 700 16; 0 0 1]\ncam1=[700 0 24; 0 700 16; 0 0 1]\n"
        "doffs=0\nbaseline=100\nwidth=48\nheight=32\n"
    )
    return text + (f"ndisp={ndisp}\n" if ndisp is not None else "")


def scene(d: Path, *, seed: int = 0, calib: bool = True, rgb: bool = False) -> Path:
    save_pair(d, "im0.png", "im1.png", seed=seed, rgb=rgb)
    if calib:
        (d / "calib.txt").write_text(calib_txt())
    return d


def kitti_set(root: Path) -> Path:
    for sub in ("image_2", "image_3", "calib"):
        (root / sub).mkdir(parents=True)
    rng = np.random.default_rng(7)
    left = rng.integers(0, 256, (*SHAPE, 3), dtype=np.uint8)
    Image.fromarray(left).save(root / "image_2" / "000000_10.png")
    Image.fromarray(np.roll(left, -3, axis=1)).save(root / "image_3" / "000000_10.png")
    rows = {0: "0", 1: "-70", 2: "0", 3: "-70"}
    (root / "calib" / "000000.txt").write_text(
        "".join(f"P{i}: 700 0 24 {tx} 0 700 16 0 0 0 1 0\n" for i, tx in rows.items())
    )
    return root


def run(capsys: pytest.CaptureFixture[str], *argv: Any) -> tuple[int, str, str]:
    try:
        status = cli.main(["batch", *(str(a) for a in argv)])
    except SystemExit as exc:
        status = int(exc.code or 0)
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def report_of(path: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads(path.read_text())
    return data


def record_of(out: Path, stem: str) -> dict[str, Any]:
    return report_of(out / f"{stem}.record.json")


# --- output locations, checked before any work -----------------------------------------------
def test_report_into_a_missing_folder_is_refused_before_any_pair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene(tmp_path / "in" / "a")
    out, report = tmp_path / "out", tmp_path / "missing" / "report.json"
    status, _, err = run(capsys, tmp_path / "in", "-o", out, "--report", report, "--quiet")
    assert status == 2
    assert err == (
        f"stereodepth batch: error: --report {report}: the folder {str(report.parent)!r} "
        "does not exist\n"
    )
    assert not out.exists()  # no pair was computed
    # a report inside OUTDIR (created by the job) is fine
    status, _, _ = run(capsys, tmp_path / "in", "-o", out, "--report", out / "r.json", "--quiet")
    assert status == 0 and report_of(out / "r.json")["counts"]["ok"] == 1


@pytest.mark.parametrize("given", [True, False])
def test_a_read_only_report_is_refused_before_any_pair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], given: bool
) -> None:
    # A report kept read-only, given with --report or left in OUTDIR by an earlier run: the
    # job failed with exit 1 after matching every pair; now a usage error before any pair.
    scene(tmp_path / "in" / "a")
    out = tmp_path / "out"
    out.mkdir()
    report = tmp_path / "kept.json" if given else out / "report.json"
    report.write_text("{}")
    report.chmod(0o444)
    try:
        argv = ["--report", report] if given else []
        status, text, err = run(capsys, tmp_path / "in", "-o", out, *argv, "--quiet")
    finally:
        report.chmod(0o644)
    assert status == 2
    assert text == ""
    named = f"--report {report}" if given else f"-o {out}"
    assert err == (
        f"stereodepth batch: error: {named}: cannot write {report.name}: the file is read-only "
        "(no write permission); make it writable or choose another path"
        + ("" if given else " (or give --report FILE)")
        + "\n"
    )
    assert report.read_text() == "{}"
    assert [p.name for p in out.iterdir()] == ([] if given else ["report.json"])


def test_a_read_only_output_of_a_pair_that_fails_is_kept(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A result made read-only to keep it: a --force rerun cannot replace it, so the pair
    # fails; its other stale outputs go, as for any failed pair, but that file was removed
    # too (the writers refuse it, the clean-up of the failed pair did not).
    inp, out = tmp_path / "in", tmp_path / "out"
    scene(inp / "teddy")
    assert run(capsys, inp, "-o", out, "--quiet")[0] == 0
    kept = out / "teddy.disparity.npy"
    before = kept.read_bytes()
    kept.chmod(0o444)
    try:
        status, _, err = run(capsys, inp, "-o", out, "--force", "--quiet")
        assert status == 1
        assert "failed teddy: " in err and "teddy.disparity.npy: the file is read-only" in err
        assert kept.read_bytes() == before
        record = record_of(out, "teddy")
        assert record["status"] == "failed"
        assert [Path(p).name for p in record["removed"]] == ["teddy.depth.npy"]
    finally:
        kept.chmod(0o644)


# --- pair names ---------------------------------------------------------------------------------
def test_the_same_pair_name_twice_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    save_pair(tmp_path / "in", "x_cam0.png", "x_cam1.png")
    status, _, err = run(
        capsys, tmp_path / "in", "-o", tmp_path / "out", "--pair-names", "cam0", "cam0"
    )
    assert status == 2
    assert err.startswith("stereodepth batch: error: --pair-names: the left and right names")
    assert not (tmp_path / "out").exists()
    with pytest.raises(batch.UsageError, match="pair_names: the left and right names must differ"):
        batch.find_pairs(tmp_path / "in", pair_names=[("cam0", "cam0")])
    with pytest.raises(batch.UsageError, match="neither name may be part of the other"):
        batch.find_pairs(tmp_path / "in", pair_names=[("cam", "cam1")])
    pairs = batch.find_pairs(tmp_path / "in", pair_names=[("cam0", "cam1")])
    assert [(p.left.name, p.right.name) for p in pairs] == [("x_cam0.png", "x_cam1.png")]


# --- the report and the records never collide ---------------------------------------------------
def test_a_scene_named_report_and_the_report_never_collide(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    inp, out = tmp_path / "in", tmp_path / "out"
    scene(inp / "report", seed=1)
    scene(inp / "teddy", seed=2)
    assert run(capsys, inp, "-o", out, "--quiet")[0] == 0
    assert report_of(out / "report.json")["counts"] == {
        "ok": 2,
        "skipped": 0,
        "failed": 0,
        "cancelled": 0,
    }
    assert record_of(out, "report")["status"] == "ok"
    # the re-run finds both records intact: nothing is recomputed
    assert run(capsys, inp, "-o", out, "--quiet")[0] == 0
    assert report_of(out / "report.json")["counts"]["skipped"] == 2
    # a report named like a pair's file is refused; one named like the old records is fine
    status, _, err = run(capsys, inp, "-o", out, "--report", out / "teddy.record.json")
    assert status == 2 and "pair 'teddy' writes that file" in err
    assert run(capsys, inp, "-o", out, "--report", out / "teddy.json", "--quiet")[0] == 0
    assert report_of(out / "teddy.json")["counts"]["skipped"] == 2
    assert record_of(out, "teddy")["status"] == "ok"


# --- no pair goes missing silently --------------------------------------------------------------
def test_nested_scenes_and_a_kitti_set_among_them_are_found(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    inp = tmp_path / "in"
    scene(inp / "middlebury" / "2014" / "teddy", seed=1)  # three levels down
    kitti_set(inp / "kitti")
    scene(inp / "a" / "b" / "c" / "too-deep", seed=2)  # four levels: not searched
    (inp / "photos").mkdir()
    Image.fromarray(np.zeros(SHAPE, np.uint8)).save(inp / "photos" / "holiday.png")
    (inp / ".hidden").mkdir()
    found = batch.discover(inp)
    assert [p.stem for p in found.pairs] == ["kitti_000000_10", "middlebury_2014_teddy"]
    assert found.pairs[0].kitti_cams == (2, 3)
    skipped = {path.relative_to(inp).as_posix(): why for path, why in found.skipped}
    assert skipped == {
        "a/b/c/too-deep": "not searched: more than 3 levels below INPUT",
        "photos": "1 image but no pair (no left image named with im0/im1, left/right, "
        "Left/Right, LEFT/RIGHT; --pair-names LEFT RIGHT names others)",
    }
    out = tmp_path / "out"
    status, _, err = run(capsys, inp, "-o", out, "--num-disparities", "16")
    assert status == 0
    assert f"stereodepth batch: note: skipped {inp / 'photos'}: 1 image but no pair" in err
    assert f"stereodepth batch: note: skipped {inp / 'a/b/c/too-deep'}: not searched" in err
    report = report_of(out / "report.json")
    assert report["counts"]["ok"] == 2
    assert sum("skipped" in n for n in report["notes"]) == 2
    assert record_of(out, "kitti_000000_10")["calibration_source"] == str(
        inp / "kitti" / "calib" / "000000.txt"
    )


def test_right_images_without_a_left_one_are_listed_as_skipped(tmp_path: Path) -> None:
    # A right image whose left one is missing (or named otherwise) went missing silently.
    inp = tmp_path / "in"
    (inp / "left").mkdir(parents=True)
    (inp / "right").mkdir()
    for name in ("0001.png", "0002.png"):
        save_pair(inp, f"left/{name}", f"right/{name}")
    Image.fromarray(np.zeros(SHAPE, np.uint8)).save(inp / "right" / "0003.png")
    Image.fromarray(np.zeros(SHAPE, np.uint8)).save(inp / "right" / "0004.jpg")
    found = batch.discover(inp)
    assert [p.stem for p in found.pairs] == ["0001", "0002"]
    assert found.skipped == [
        (inp / "right", "2 images with no left image of the same name in left (0003.png, 0004.jpg)")
    ]


@pytest.mark.parametrize(
    ("lefts", "rights", "alone"),
    [
        (["0001_left.png"], ["0001_right.png", "0003_right.png"], "0003_left.png"),
        (
            ["im0.png"],
            ["im1.png", "x_im1.png", "im1E.png", "im10.png", "copyright.png"],
            "x_im0.png",
        ),
    ],
)
def test_right_images_named_with_a_token_and_no_left_one_are_listed_as_skipped(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    lefts: list[str],
    rights: list[str],
    alone: str,
) -> None:
    # The same in a folder of pairs named with tokens: 0003_right.png (or x_im1.png) with no
    # left image went missing silently, while a left image with no right is a failed pair.
    # The token must stand as a whole word: Middlebury 2014's im1E.png (the right camera's
    # other exposure), im10.png or copyright.png are no right images.
    inp = tmp_path / "in" / "f"
    inp.mkdir(parents=True)
    save_pair(inp, lefts[0], rights[0])
    for name in rights[1:]:
        Image.fromarray(np.zeros(SHAPE, np.uint8)).save(inp / name)
    found = batch.discover(tmp_path / "in")
    assert len(found.pairs) == 1
    orphan = rights[1]
    assert found.skipped == [(inp / orphan, f"a right image with no left image {alone}")]
    out = tmp_path / "out"
    argv = ["-o", out, "--num-disparities", "16", "--focal-px", "700", "--baseline-mm", "100"]
    status, _, err = run(capsys, tmp_path / "in", *argv)
    assert status == 0, err
    note = f"stereodepth batch: note: skipped {inp / orphan}: a right image with no left image"
    assert note in err
    assert sum(orphan in n for n in report_of(out / "report.json")["notes"]) == 1


def test_a_grey_pair_beside_the_colour_pair_is_listed_as_skipped(tmp_path: Path) -> None:
    # KITTI's image_0/image_1 beside image_2/image_3: only the colour pairs are used, and the
    # grey ones went missing silently.
    inp = tmp_path / "in"
    kitti_set(inp)
    (inp / "image_0").mkdir()
    (inp / "image_1").mkdir()
    save_pair(inp, "image_0/000000_10.png", "image_1/000000_10.png")
    found = batch.discover(inp)
    assert [(p.stem, p.kitti_cams) for p in found.pairs] == [("000000_10", (2, 3))]
    assert found.skipped == [
        (
            inp / "image_0",
            "image_0/image_1 beside image_2/image_3, which are used (a CSV list names the "
            "others' pairs)",
        )
    ]


def test_a_scene_beside_left_and_right_folders_is_listed_as_skipped(tmp_path: Path) -> None:
    # The other sub-folders of a folder of left/right sub-folders are not searched: a scene
    # there went missing silently.
    inp = tmp_path / "in"
    (inp / "left").mkdir(parents=True)
    (inp / "right").mkdir()
    save_pair(inp, "left/0001.png", "right/0001.png")
    scene(inp / "teddy")
    (inp / "calib").mkdir()  # no images: not listed
    found = batch.discover(inp)
    assert [p.stem for p in found.pairs] == ["0001"]
    assert found.skipped == [
        (inp / "teddy", "not searched: beside left/right (a CSV list names its pairs)")
    ]


def test_left_and_right_folders_of_folders_say_why_no_pair_is_found(tmp_path: Path) -> None:
    # left/seq1/0001.png: "no stereo pairs found ... expected ... left/right folders" named
    # the very layout it had, and no reason.
    inp = tmp_path / "in"
    (inp / "left" / "seq1").mkdir(parents=True)
    (inp / "right" / "seq1").mkdir(parents=True)
    save_pair(inp, "left/seq1/0001.png", "right/seq1/0001.png")
    with pytest.raises(
        batch.UsageError,
        match=r"no stereo pairs found .*; skipped .*left: no images in it, only folders \(which "
        r"are not searched\)$",
    ):
        batch.find_pairs(inp)


def test_nothing_found_says_what_was_skipped(tmp_path: Path) -> None:
    save_pair(tmp_path / "in" / "shots", "a.png", "b.png")
    with pytest.raises(
        batch.UsageError, match=r"no stereo pairs found .*skipped .*shots: 2 images"
    ):
        batch.find_pairs(tmp_path / "in")


def test_outdir_inside_input_is_not_searched(tmp_path: Path) -> None:
    scene(tmp_path / "teddy")
    (tmp_path / "out" / "old").mkdir(parents=True)
    Image.fromarray(np.zeros(SHAPE, np.uint8)).save(tmp_path / "out" / "old" / "left.png")
    found = batch.discover(tmp_path, exclude=[tmp_path / "out"])
    assert [p.stem for p in found.pairs] == ["teddy"] and found.skipped == []


# --- a failed re-run and stale outputs ----------------------------------------------------------
def test_a_failed_rerun_says_failed_and_leaves_no_stale_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    inp, out = tmp_path / "in", tmp_path / "out"
    scene(inp / "teddy")
    assert run(capsys, inp, "-o", out, "--ply", "--quiet")[0] == 0
    names = {"teddy.disparity.npy", "teddy.depth.npy", "teddy.ply", "teddy.record.json"}
    assert {p.name for p in out.glob("teddy.*")} == names
    data = (inp / "teddy" / "im1.png").read_bytes()
    (inp / "teddy" / "im1.png").write_bytes(data[: len(data) // 3])  # now corrupt
    status, _, err = run(capsys, inp, "-o", out, "--quiet")
    assert status == 1 and "failed teddy: cannot decode image" in err
    record = record_of(out, "teddy")
    assert record["status"] == "failed" and "cannot decode image" in record["error"]
    assert sorted(Path(p).name for p in record["removed"]) == sorted(names - {"teddy.record.json"})
    assert {p.name for p in out.glob("teddy.*")} == {"teddy.record.json"}
    assert report_of(out / "report.json")["pairs"][0]["status"] == "failed"


def test_a_pair_failing_between_two_writes_leaves_no_output_and_a_failed_record(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A folder where the depth goes: the disparity was written, then the depth failed, then
    # removing the pair's files stopped at that folder (IsADirectoryError): the new disparity
    # stayed without a record, and the error blamed the record.
    # (Without --force such a folder, which no record lists, is refused before any pair.)
    inp, out = tmp_path / "in", tmp_path / "out"
    scene(inp / "teddy")
    scene(inp / "bear", seed=1)
    (out / "teddy.depth.npy").mkdir(parents=True)
    status, _, err = run(capsys, inp, "-o", out, "--quiet")
    assert status == 2 and "holds teddy.depth.npy, which pair 'teddy' would write" in err, err
    assert [p.name for p in out.iterdir()] == ["teddy.depth.npy"]
    status, _, err = run(capsys, inp, "-o", out, "--quiet", "--force")
    assert status == 1
    assert (
        f"failed teddy: [Errno 21] cannot write a file over a folder: '{out}/teddy.depth.npy'\n"
        in err
    )
    assert "could not be written" not in err
    record = record_of(out, "teddy")
    assert record["status"] == "failed" and "cannot write a file over a folder" in record["error"]
    assert record["removed"] == [str(out / "teddy.disparity.npy")]
    assert {p.name for p in out.glob("teddy.*")} == {"teddy.record.json", "teddy.depth.npy"}
    assert (out / "teddy.depth.npy").is_dir()  # not ours to remove
    assert record_of(out, "bear")["status"] == "ok"


@pytest.mark.parametrize("named", ["teddy.disparity.npy", "teddy.ply"])
def test_a_file_of_the_users_at_an_output_path_is_not_replaced_without_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], named: str
) -> None:
    # A file that no batch job wrote (no record lists it) at one of a pair's output paths was
    # replaced without a word, where the outputs of a job from other images are refused.
    inp, out = tmp_path / "in", tmp_path / "out"
    scene(inp / "teddy")
    out.mkdir()
    (out / named).write_bytes(b"mine")
    status, _, err = run(capsys, inp, "-o", out, "--ply", "--quiet")
    assert status == 2, err
    assert f"holds {named}, which pair 'teddy' would write and no batch job's record" in err
    assert err.count("\n") == 1 and "--force" in err
    assert (out / named).read_bytes() == b"mine"
    assert sorted(p.name for p in out.iterdir()) == [named]
    # a record that lists it (an earlier run's) makes it the job's own: resumed, not refused
    assert run(capsys, inp, "-o", out, "--ply", "--quiet", "--force")[0] == 0
    assert run(capsys, inp, "-o", out, "--ply", "--quiet")[0] == 0
    assert (out / named).read_bytes() != b"mine"


def test_a_changed_run_removes_the_outputs_it_no_longer_writes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    inp, out = tmp_path / "in", tmp_path / "out"
    scene(inp / "teddy")
    assert run(capsys, inp, "-o", out, "--ply", "--quiet")[0] == 0
    status, printed, _ = run(capsys, inp, "-o", out)  # without --ply: the .ply is stale
    assert status == 0 and "removed 1 stale output file of earlier runs" in printed
    assert not (out / "teddy.ply").exists()
    assert record_of(out, "teddy")["removed"] == [str(out / "teddy.ply")]
    assert run(capsys, inp, "-o", out, "--format", "png16", "--quiet")[0] == 0
    assert {p.name for p in out.glob("teddy.*")} == {
        "teddy.disparity.png",
        "teddy.depth.png",
        "teddy.record.json",
    }
    # a file the record does not list, even with a pair's name, is left alone
    (out / "teddy.disparity.pfm").write_bytes(b"mine")
    assert run(capsys, inp, "-o", out, "--force", "--quiet")[0] == 0
    assert (out / "teddy.disparity.pfm").read_bytes() == b"mine"


@pytest.mark.parametrize(
    "text",
    ["[1, 2]", '"ok"', "null", '{"status": "ok", "settings": ' + "[" * 50_000 + "]" * 50_000 + "}"],
)
def test_a_record_that_is_not_an_object_is_redone_not_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str
) -> None:
    # A record edited by hand (a JSON list, a string) raised AttributeError and one nested
    # deeper than the recursion limit RecursionError, in all three readers of records (resume,
    # stale outputs, discovery of an OUTDIR inside INPUT): a traceback instead of a rerun.
    inp = tmp_path / "in"
    out = inp / "out"  # inside INPUT: discovery reads the records too
    scene(inp / "teddy")
    assert run(capsys, inp, "-o", out, "--quiet")[0] == 0
    (out / "teddy.record.json").write_text(text)
    status, printed, err = run(capsys, inp, "-o", out)
    assert (status, err) == (0, ""), err
    assert "1 done" in printed
    assert record_of(out, "teddy")["status"] == "ok"


def test_a_pair_whose_dask_worker_kept_dying_gets_a_failed_record(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The Dask runner's failure without a result from the task (KilledWorker) is written the
    same way as any other failure: the earlier outputs go, the record says failed."""
    inp, out = tmp_path / "in", tmp_path / "out"
    scene(inp / "teddy")
    assert run(capsys, inp, "-o", out, "--ply", "--quiet")[0] == 0
    pair = batch.resolve_calibration(batch.find_pairs(inp))[0]
    head = batch.records.record_head(pair, "failed", "KilledWorker: the worker died 3 times")
    rec = batch.compute.record_failure(pair, batch.BatchOptions(out_dir=out), head)
    assert rec["status"] == "failed" and len(rec["removed"]) == 3
    assert {p.name for p in out.glob("teddy.*")} == {"teddy.record.json"}
    assert record_of(out, "teddy")["error"] == "KilledWorker: the worker died 3 times"


# --- calibration precedence ---------------------------------------------------------------------
def test_calibration_precedence_is_stated_per_pair_and_the_message_is_true(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    inp, out = tmp_path / "in", tmp_path / "out"
    scene(inp / "a", seed=1)
    scene(inp / "b", seed=2)
    rig = ["--focal-px", "650", "--baseline-mm", "120"]
    status, _, err = run(capsys, inp, "-o", out, *rig)
    assert status == 2
    assert err == (
        "stereodepth batch: error: --num-disparities is required with --focal-px and "
        f"--baseline-mm: they replace the pairs' own calibration files (2 found, e.g. "
        f"{inp / 'a' / 'calib.txt'}), whose ndisp is then not used\n"
    )
    status, _, err = run(capsys, inp, "-o", out, *rig, "--num-disparities", "16")
    assert status == 0
    assert err == (
        "stereodepth batch: note: calibration: --focal-px/--baseline-mm for every pair; 2 "
        f"pairs' own calibration files (e.g. {inp / 'a' / 'calib.txt'}) not used\n"
    )
    rec = record_of(out, "a")
    assert rec["calibration_source"] == "--focal-px/--baseline-mm"
    assert rec["calibration_not_used"] == str(inp / "a" / "calib.txt")
    assert rec["settings"]["calibration"]["focal_px"] == 650.0
    assert any("not used" in n for n in report_of(out / "report.json")["notes"])
    # one pair: "1 pair's own calibration file", not "1 pair' own"
    status, _, err = run(capsys, inp / "a", "-o", tmp_path / "one", *rig, "--num-disparities", "16")
    assert (status, err) == (
        0,
        "stereodepth batch: note: calibration: --focal-px/--baseline-mm for every pair; 1 "
        f"pair's own calibration file (e.g. {inp / 'a' / 'calib.txt'}) not used\n",
    )
    # --calib FILE: named as such
    (tmp_path / "rig.txt").write_text(calib_txt(ndisp=None))
    status, _, err = run(capsys, inp, "-o", out, "--calib", tmp_path / "rig.txt")
    assert status == 2
    assert err == (
        f"stereodepth batch: error: --num-disparities is required: --calib {tmp_path / 'rig.txt'} "
        "has no ndisp\n"
    )
    # each pair's own file: named by its path, nothing replaced
    assert run(capsys, inp, "-o", tmp_path / "own", "--quiet")[0] == 0
    rec = record_of(tmp_path / "own", "b")
    assert rec["calibration_source"] == str(inp / "b" / "calib.txt")
    assert rec["calibration_not_used"] is None


def test_kitti_without_num_disparities_names_the_kitti_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    inp = kitti_set(tmp_path / "in")
    status, _, err = run(capsys, inp, "-o", tmp_path / "out")
    assert status == 2
    assert err == (
        "stereodepth batch: error: --num-disparities is required: the pairs' calibration "
        f"files have no ndisp (e.g. {inp / 'calib' / '000000.txt'}); KITTI calibration files "
        "never have one\n"
    )


# --- options and extras, before the first pair --------------------------------------------------
def test_an_impossible_depth_range_is_refused_before_the_first_pair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene(tmp_path / "in" / "a")
    scene(tmp_path / "in" / "b", seed=1)
    out = tmp_path / "out"
    status, printed, err = run(
        capsys, tmp_path / "in", "-o", out, "--min-depth-m", "5", "--max-depth-m", "1"
    )
    assert (status, printed) == (2, "")
    assert err == (
        "stereodepth batch: error: --max-depth-m must be >= --min-depth-m, got --min-depth-m 5 "
        "and --max-depth-m 1\n"
    )
    assert not out.exists()


@pytest.mark.parametrize("command", ["batch", "eval"])
def test_missing_pillow_is_one_line_before_any_work(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    command: str,
) -> None:
    """Without Pillow, both commands stop at once (even before looking at INPUT, which is
    empty here) with one line naming the package and the extra that installs it."""
    monkeypatch.setitem(sys.modules, "PIL", None)
    monkeypatch.setitem(sys.modules, "PIL.Image", None)
    (tmp_path / "in").mkdir()
    argv = [command, str(tmp_path / "in")]
    if command == "batch":
        argv += ["-o", str(tmp_path / "out"), "--quiet"]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert err == (
        f"stereodepth {command}: error: reading images needs Pillow, which is not installed: "
        'pip install "stereodepth[batch]"\n'
    )
    assert not (tmp_path / "out").exists()


# --- colour order -------------------------------------------------------------------------------
def test_channel_order_is_passed_to_the_matcher(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    if "channel_order" not in inspect.signature(stereodepth.StereoMatcher).parameters:
        pytest.skip("this matcher has no channel_order yet")
    d = scene(tmp_path / "in" / "a", rgb=True)
    out = tmp_path / "out"
    assert run(capsys, tmp_path / "in", "-o", out, "--channel-order", "bgr", "--quiet")[0] == 0
    left = np.asarray(Image.open(d / "im0.png"))
    right = np.asarray(Image.open(d / "im1.png"))
    want = stereodepth.block_match(left, right, num_disparities=16, channel_order="bgr")
    np.testing.assert_array_equal(np.load(out / "a.disparity.npy"), want)
    assert record_of(out, "a")["settings"]["matcher"]["channel_order"] == "bgr"


def test_channel_order_bgr_colours_the_point_cloud_in_rgb(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A pair stored with its channels swapped (B, G, R), matched with --channel-order bgr:
    the PLY's red, green, blue were the file's channels as stored, so the cloud's blue sky
    came out red; write_ply takes RGB (the README: colors=frame[..., ::-1] for a BGR frame)."""
    d = scene(tmp_path / "in" / "a", rgb=True)
    out = tmp_path / "out"
    argv = [tmp_path / "in", "-o", out, "--channel-order", "bgr", "--ply", "--quiet"]
    assert run(capsys, *argv)[0] == 0
    left = np.asarray(Image.open(d / "im0.png"))
    right = np.asarray(Image.open(d / "im1.png"))
    disparity = stereodepth.block_match(left, right, num_disparities=16, channel_order="bgr")
    points = stereodepth.reproject(disparity, focal_px=700, baseline_m=0.1, cx_px=24, cy_px=16)
    keep = np.isfinite(points).all(axis=-1)
    assert keep.sum() > 0
    _, vertex = read_ply(out / "a.ply")
    np.testing.assert_array_equal(
        np.stack([vertex["x"], vertex["y"], vertex["z"]], -1), points[keep]
    )
    colours = np.stack([vertex["red"], vertex["green"], vertex["blue"]], -1)
    np.testing.assert_array_equal(colours, left[..., ::-1][keep])


# --- the lock file ------------------------------------------------------------------------------
def test_the_lock_file_is_removed_when_the_job_ends(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene(tmp_path / "in" / "a")
    out = tmp_path / "out"
    assert run(capsys, tmp_path / "in", "-o", out, "--quiet")[0] == 0
    assert not (out / batch.LOCK_NAME).exists()
    (tmp_path / "in" / "a" / "im1.png").unlink()  # a failing pair: the job still ends cleanly
    assert run(capsys, tmp_path / "in", "-o", out, "--quiet")[0] == 1
    assert not (out / batch.LOCK_NAME).exists()
    # a lock file left by a killed job does not stop the next one
    (out / batch.LOCK_NAME).write_text("")
    assert run(capsys, tmp_path / "in", "-o", out, "--quiet")[0] == 1
    assert not (out / batch.LOCK_NAME).exists()


def test_a_middlebury_calibration_of_another_resolution_fails_the_pair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A calib.txt's width and height name the images it calibrates: Middlebury's full-size
    file beside its quarter-size images would give depths 4 times too large, silently."""
    inp = tmp_path / "in"
    scene(inp / "good")
    scene(inp / "half", seed=1, calib=False)
    (inp / "half" / "calib.txt").write_text(calib_txt().replace("width=48", "width=96"))
    out = tmp_path / "out"
    status, _, err = run(capsys, inp, "-o", out, "--quiet")
    assert status == 1, err
    assert record_of(out, "good")["status"] == "ok"
    bad = record_of(out, "half")
    assert bad["status"] == "failed"
    assert bad["error"] == (
        f"the images are 48x32 px and the calibration {inp / 'half' / 'calib.txt'} is for "
        "96x32 px (its width and height): a calibration of another resolution gives wrong depths"
    )
    assert not list(out.glob("half.*.npy"))


@pytest.mark.parametrize("shared", ["beside", "--calib", "csv"])
def test_kitti_grey_pair_reads_its_own_cameras(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], shared: str
) -> None:
    """KITTI odometry's grey set: sequences/NN/image_0, image_1 and one calib.txt (P0 to P3).
    The pair is cameras 0 and 1; it once got the colour pair's P2/P3 baseline, silently."""
    seq = tmp_path / "in" / "00"
    for sub in ("image_0", "image_1"):
        (seq / sub).mkdir(parents=True)
    rng = np.random.default_rng(7)
    left = rng.integers(0, 256, SHAPE, dtype=np.uint8)
    Image.fromarray(left).save(seq / "image_0" / "000000.png")
    Image.fromarray(np.roll(left, -3, axis=1)).save(seq / "image_1" / "000000.png")
    rows = {0: "0", 1: "-70", 2: "42", 3: "-35"}  # grey baseline 0.1 m, colour 0.11 m
    calib = (seq if shared == "beside" else tmp_path) / "calib.txt"
    calib.write_text("".join(f"P{i}: 700 0 24 {tx} 0 700 16 0 0 0 1 0\n" for i, tx in rows.items()))
    out = tmp_path / "out"
    extra = ["--calib", calib] if shared != "beside" else []
    inp = tmp_path / "in"
    if shared == "csv":  # a CSV list of KITTI images: the cameras of their folders too
        inp = tmp_path / "pairs.csv"
        inp.write_text("in/00/image_0/000000.png,in/00/image_1/000000.png,00_000000\n")
    status, _, err = run(capsys, inp, "-o", out, "--num-disparities", 16, *extra)
    assert status == 0, err
    rig = record_of(out, "00_000000")["settings"]["calibration"]
    assert rig["baseline_m"] == pytest.approx(0.1, rel=1e-12)


def test_one_kitti_calib_for_grey_and_colour_pairs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One --calib for a CSV list of a grey (image_0/image_1) and a colour (image_2/image_3)
    pair: each reads its own cameras (all once read those of the first pair)."""
    seq = tmp_path / "00"
    rng = np.random.default_rng(8)
    left = rng.integers(0, 256, SHAPE, dtype=np.uint8)
    for a, b in (("image_0", "image_1"), ("image_2", "image_3")):
        for sub, image in ((a, left), (b, np.roll(left, -3, axis=1))):
            (seq / sub).mkdir(parents=True)
            Image.fromarray(image).save(seq / sub / "000000.png")
    rows = {0: "0", 1: "-70", 2: "42", 3: "-35"}  # grey baseline 0.1 m, colour 0.11 m
    calib = tmp_path / "calib.txt"
    calib.write_text("".join(f"P{i}: 700 0 24 {tx} 0 700 16 0 0 0 1 0\n" for i, tx in rows.items()))
    (tmp_path / "pairs.csv").write_text(
        "00/image_0/000000.png,00/image_1/000000.png,grey\n"
        "00/image_2/000000.png,00/image_3/000000.png,colour\n"
    )
    out = tmp_path / "out"
    argv = [tmp_path / "pairs.csv", "-o", out, "--num-disparities", 16, "--calib", calib]
    status, _, err = run(capsys, *argv)
    assert status == 0, err
    for stem, baseline in (("grey", 0.1), ("colour", 0.11)):
        rig = record_of(out, stem)["settings"]["calibration"]
        assert rig["baseline_m"] == pytest.approx(baseline, rel=1e-12), stem


def test_jsonable_turns_every_non_finite_float_into_null() -> None:
    # numpy's float32 and float16 are not Python floats: their NaN and inf went through as
    # NaN, which the record writer (json.dump with allow_nan=False) then refused.
    from stereodepth.batch.records import jsonable

    value = {"a": np.float32("nan"), "b": [np.float16("inf"), np.float64("-inf")], "c": 1.5}
    assert jsonable(value) == {"a": None, "b": [None, None], "c": 1.5}
    assert json.dumps(jsonable(value), allow_nan=False) == (
        '{"a": null, "b": [null, null], "c": 1.5}'
    )
    assert jsonable(np.int64(3)) == 3 and type(jsonable(np.int64(3))) is int


def test_a_calib_txt_ndisp_beyond_the_matchers_names_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The pair failed with the matcher's "num_disparities must be an integer in [1, 4096],
    # got 5000", which named neither the calib.txt nor what to do.
    inp, out = tmp_path / "in", tmp_path / "out"
    d = scene(inp / "teddy")
    (d / "calib.txt").write_text(calib_txt(ndisp=5000))
    status, _, err = run(capsys, inp, "-o", out, "--quiet")
    assert status == 1
    assert f"{d / 'calib.txt'}: ndisp=5000 is more than the matchers search (4096)" in err
    assert "give --num-disparities" in record_of(out, "teddy")["error"]
    assert run(capsys, inp, "-o", out, "--quiet", "--num-disparities", "16")[0] == 0


def test_a_folder_reached_twice_through_a_link_is_searched_once(tmp_path: Path) -> None:
    """``in/d/loop -> ..`` made the search walk INPUT again under d/loop: every pair was
    matched a second time, under another stem (d_loop_teddy), and a link to a scene folder
    matched that scene twice."""
    inp = tmp_path / "in"
    scene(inp / "teddy")
    (inp / "d").mkdir()
    (inp / "d" / "loop").symlink_to("..", target_is_directory=True)
    (inp / "z_again").symlink_to("teddy", target_is_directory=True)
    found = batch.discover(inp)
    assert [p.stem for p in found.pairs] == ["teddy"]
    skipped = {path.relative_to(inp).as_posix(): why for path, why in found.skipped}
    assert skipped == {
        "d/loop": f"the same folder as {inp} (a link): not searched again",
        "z_again": f"the same folder as {inp / 'teddy'} (a link): not searched again",
    }


def test_outputs_in_the_kitti_left_folder_are_not_pairs_on_the_next_run(
    tmp_path: Path, stereo_data_dir: Path
) -> None:
    """Outputs beside the left images of a KITTI set (-o training/image_2): the depth and
    disparity PNGs of --format png16 and the previews were taken for left images on the next
    run, which pair 000070_10 writes, so the same command was refused ('which is the input
    ...: choose another OUTDIR'). The shared KITTI scene, its outputs checked."""
    scene = stereo_data_dir / "kitti2012-000070"
    root = tmp_path / "training"
    for side, name in (("image_0", "left.png"), ("image_1", "right.png")):
        (root / side).mkdir(parents=True)
        (root / side / "000070_10.png").write_bytes((scene / name).read_bytes())
    meta = json.loads((scene / "meta.json").read_text())
    out = root / "image_0"
    argv = [
        "batch", str(root), "-o", str(out), "--format", "png16", "--preview",
        "--focal-px", str(meta["focal_px"]), "--baseline-mm", str(meta["baseline_mm"]),
        "--num-disparities", "160", "--threads", "1", "--quiet",
    ]  # fmt: skip
    assert cli.main(argv) == 0
    first = {p.name: p.read_bytes() for p in out.iterdir() if p.name != "report.json"}
    assert cli.main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    assert [(p["stem"], p["status"]) for p in report["pairs"]] == [("000070_10", "skipped")]
    assert (
        f"skipped {out / '000070_10.depth.png'}: an output of pair '000070_10' in OUTDIR, "
        "not a pair" in report["notes"]
    )
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.name != "report.json"} == first
    left = stereodepth.io.read_image(out / "000070_10.png")
    right = stereodepth.io.read_image(root / "image_1" / "000070_10.png")
    disparity = stereodepth.block_match(left, right, num_disparities=160, threads=1)
    depth = stereodepth.disparity_to_depth(
        disparity,
        focal_px=meta["focal_px"],
        baseline_m=meta["baseline_mm"] / 1000,
        dtype=np.uint16,
    )
    np.testing.assert_array_equal(stereodepth.io.read_image(out / "000070_10.depth.png"), depth)
    written = stereodepth.io.read_disparity_png16(out / "000070_10.disparity.png")
    np.testing.assert_array_equal(np.isnan(written), ~(disparity > 0) | np.isnan(disparity))
    assert np.nanmax(np.abs(written - disparity)) <= 1 / 512


def test_batch_options_are_checked_when_made(tmp_path: Path) -> None:
    """The Python API: a str OUTDIR was an AttributeError from run_batch ('str' object has no
    attribute 'parents'); an unknown format failed every pair with "KeyError: 'tif'" and an
    unknown method every pair too, each leaving a failed record in OUTDIR."""
    scene(tmp_path / "in" / "a")
    pairs = batch.resolve_calibration(batch.find_pairs(tmp_path / "in"))
    report = batch.run_batch(pairs, batch.BatchOptions(out_dir=str(tmp_path / "out")), threads=1)
    assert report.counts["ok"] == 1
    np.testing.assert_array_equal(
        np.load(tmp_path / "out" / "a.disparity.npy"),
        stereodepth.block_match(
            np.asarray(Image.open(tmp_path / "in" / "a" / "im0.png")),
            np.asarray(Image.open(tmp_path / "in" / "a" / "im1.png")),
            num_disparities=16,
        ),
    )
    with pytest.raises(
        TypeError, match=r"out_dir must be a path \(str or os.PathLike\), got int 3"
    ):
        batch.BatchOptions(out_dir=3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"format must be one of 'npy', 'png16', 'pfm', got 'tif'"):
        batch.BatchOptions(out_dir=tmp_path / "x", format="tif")
    with pytest.raises(ValueError, match=r"method must be one of 'bm', 'sgm', got 'xx'"):
        batch.BatchOptions(out_dir=tmp_path / "x", method="xx")
    with pytest.raises(TypeError, match=r"method must be one of 'bm', 'sgm', got NoneType None"):
        batch.BatchOptions(out_dir=tmp_path / "x", method=None)  # type: ignore[arg-type]
    assert not (tmp_path / "x").exists()


def test_a_folder_that_cannot_be_searched_is_skipped_with_the_reason(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A sub-folder without read permission (Path.is_dir raises PermissionError for what is
    # inside it) ended the whole job; it is listed and the other folders' pairs are found.
    # (As root chmod cannot take the permission away, so the error is made by the stand-in.)
    from stereodepth.batch import discovery

    scene(tmp_path / "in" / "good")
    locked = tmp_path / "in" / "locked"
    (locked / "image_2").mkdir(parents=True)
    real_is_dir = Path.is_dir

    def is_dir(self: Path) -> bool:
        if self.parent == locked:
            raise PermissionError(13, "Permission denied", str(self))
        return real_is_dir(self)

    monkeypatch.setattr(Path, "is_dir", is_dir)
    found = discovery.discover(tmp_path / "in")
    assert [p.stem for p in found.pairs] == ["good"]
    assert (locked, "cannot be searched: Permission denied") in found.skipped
