"""stereodepth batch: finding pairs, computing them, failing one pair at a time, atomic outputs,
resuming, Ctrl-C and kill -9, and the same job on a real Dask LocalCluster."""

from __future__ import annotations

import contextlib
import io as io_module
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import batch, cli, io

Image = pytest.importorskip("PIL.Image")

SHAPE = (48, 64)
CALIB: dict[str, Any] = {
    "focal": 700.0,
    "cx": 31.5,
    "cx1": 33.5,
    "cy": 23.5,
    "baseline_mm": 120.0,
    "ndisp": 16,
}


# --- building inputs --------------------------------------------------------------------------
def random_pair(
    seed: int, shift: int, *, shape: tuple[int, int] = SHAPE, rgb: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """A random-dot pair whose true disparity is ``shift`` everywhere."""
    rng = np.random.default_rng(seed)
    left = rng.integers(0, 256, (*shape, 3) if rgb else shape, dtype=np.uint8)
    return left, np.roll(left, -shift, axis=1)


def calib_text(ndisp: int | None = 16) -> str:
    c = CALIB
    text = (
        f"cam0=[{c['focal']} 0 {c['cx']}; 0 {c['focal']} {c['cy']}; 0 0 1]\n"
        f"cam1=[{c['focal']} 0 {c['cx1']}; 0 {c['focal']} {c['cy']}; 0 0 1]\n"
        f"doffs={c['cx1'] - c['cx']}\nbaseline={c['baseline_mm']}\n"
        f"width={SHAPE[1]}\nheight={SHAPE[0]}\n"
    )
    return text + (f"ndisp={ndisp}\n" if ndisp is not None else "")


def middlebury_folder(root: Path, n: int, *, first_seed: int = 0) -> list[str]:
    """``n`` Middlebury scene folders (im0.png, im1.png, calib.txt); returns their names."""
    names = []
    for i in range(n):
        d = root / f"scene{i:02d}"
        d.mkdir(parents=True)
        left, right = random_pair(first_seed + i, 2 + i % 5)
        Image.fromarray(left).save(d / "im0.png")
        Image.fromarray(right).save(d / "im1.png")
        (d / "calib.txt").write_text(calib_text())
        names.append(d.name)
    return names


def run_cli(*argv: str | Path) -> int:
    return cli.main([str(a) for a in argv])


def report_of(out: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((out / "report.json").read_text())
    return data


def temp_files(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if p.name.endswith(".tmp"))


def expected_maps(scene: Path, fmt: str = "npy") -> tuple[np.ndarray, np.ndarray]:
    """What batch must write for a Middlebury scene, computed directly."""
    left, right = io.read_image(scene / "im0.png"), io.read_image(scene / "im1.png")
    disparity = stereodepth.matching.block_match(left, right, num_disparities=CALIB["ndisp"])
    assert isinstance(disparity, np.ndarray)
    depth = stereodepth.disparity_to_depth(
        disparity,
        focal_px=CALIB["focal"],
        baseline_m=CALIB["baseline_mm"] / 1000,
        doffs_px=CALIB["cx1"] - CALIB["cx"],
        dtype=np.uint16 if fmt == "png16" else np.float32,
    )
    return disparity, depth


def outputs_bytes(out: Path) -> dict[str, bytes]:
    """Every output file's bytes (not the records and the report, which hold times)."""
    return {
        p.name: p.read_bytes()
        for p in sorted(out.iterdir())
        if p.suffix in (".npy", ".png", ".pfm", ".ply")
    }


# --- finding pairs ----------------------------------------------------------------------------
def test_find_pairs_in_middlebury_scene_folders(tmp_path: Path) -> None:
    names = middlebury_folder(tmp_path, 3)
    (tmp_path / "scene01" / "im1E.png").write_bytes(b"")  # Middlebury's other exposures
    (tmp_path / "notes").mkdir()  # a folder with no pair is ignored
    pairs = batch.find_pairs(tmp_path)
    assert [p.stem for p in pairs] == names
    assert pairs[1].left == tmp_path / "scene01" / "im0.png"
    assert pairs[1].right == tmp_path / "scene01" / "im1.png"
    assert pairs[1].calib_file == tmp_path / "scene01" / "calib.txt"
    # one scene folder as INPUT
    one = batch.find_pairs(tmp_path / "scene02")
    assert [(p.stem, p.left.name) for p in one] == [("scene02", "im0.png")]


def test_find_pairs_in_kitti_folders_with_calibration(tmp_path: Path) -> None:
    for sub in ("image_2", "image_3", "image_0", "image_1", "calib"):
        (tmp_path / sub).mkdir()
    for frame in ("000000_10", "000000_11", "000001_10"):
        for sub in ("image_2", "image_3"):
            Image.fromarray(np.zeros((4, 6), np.uint8)).save(tmp_path / sub / f"{frame}.png")
    (tmp_path / "image_3" / "000001_10.png").unlink()  # a missing right image
    (tmp_path / "calib" / "000000.txt").write_text(kitti_calib_2012())
    pairs = batch.find_pairs(tmp_path)
    assert [p.stem for p in pairs] == ["000000_10", "000000_11", "000001_10"]
    assert pairs[0].right == tmp_path / "image_3" / "000000_10.png"
    assert pairs[1].calib_file == tmp_path / "calib" / "000000.txt"
    assert pairs[0].kitti_cams == (2, 3)
    assert pairs[2].calib_file is None and not pairs[2].right.exists()
    resolved = batch.resolve_calibration(pairs, num_disparities=64)
    c = resolved[0].calibration
    assert c is not None
    assert c.focal_px == pytest.approx(721.5377)
    assert c.baseline_m == pytest.approx((44.85728 + 339.5242) / 721.5377)
    assert (c.cx_px, c.cy_px, c.doffs_px) == (609.5593, 172.854, 0.0)
    assert resolved[2].problem is not None and resolved[2].problem.startswith("no calibration")


def kitti_calib_2012() -> str:
    """KITTI 2012 training/calib/000000.txt: the rectified projection matrices P0..P3."""
    rows = {
        0: "0.000000e+00",
        1: "-3.875744e+02",
        2: "4.485728e+01",
        3: "-3.395242e+02",
    }
    return "".join(
        f"P{i}: 7.215377e+02 0.000000e+00 6.095593e+02 {tx} 0.000000e+00 7.215377e+02 "
        "1.728540e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00\n"
        for i, tx in rows.items()
    )


def test_read_kitti_calib_2012_and_2015(tmp_path: Path) -> None:
    p = tmp_path / "c.txt"
    p.write_text(kitti_calib_2012())
    grey = batch.read_kitti_calib(p, (0, 1))
    assert grey.baseline_m == pytest.approx(387.5744 / 721.5377)
    assert grey.focal_px == 721.5377
    rect = "\n".join(line.replace("P", "P_rect_0", 1) for line in kitti_calib_2012().splitlines())
    p.write_text("calib_time: 09-Jan-2012\n" + rect + "\n")
    assert batch.read_calibration(p) == batch.read_kitti_calib(p)  # cameras 2 and 3
    p.write_text("P2: 1 2 3\n")
    with pytest.raises(ValueError, match="P2 must be 12 numbers, got 3"):
        batch.read_kitti_calib(p)
    p.write_text(kitti_calib_2012().replace("P3:", "Q3:"))
    with pytest.raises(ValueError, match="missing P3"):
        batch.read_kitti_calib(p)


def test_find_pairs_by_name_and_in_left_right_folders(tmp_path: Path) -> None:
    a = tmp_path / "a"
    a.mkdir()
    for name in (
        "0001_left.png",
        "0001_right.png",
        "0002_left.png",
        "0002_right.png",
        "readme.txt",
    ):
        (a / name).write_bytes(b"")
    assert [(p.stem, p.right.name) for p in batch.find_pairs(a)] == [
        ("0001", "0001_right.png"),
        ("0002", "0002_right.png"),
    ]
    b = tmp_path / "b"
    for side in ("left", "right"):
        (b / side).mkdir(parents=True)
        (b / side / "f7.png").write_bytes(b"")
    assert [(p.stem, p.right) for p in batch.find_pairs(b)] == [("f7", b / "right" / "f7.png")]
    c = tmp_path / "c"
    c.mkdir()
    for name in ("x_cam0.png", "x_cam1.png"):
        (c / name).write_bytes(b"")
    with pytest.raises(batch.UsageError, match="no stereo pairs found"):
        batch.find_pairs(c)
    assert [p.right.name for p in batch.find_pairs(c, pair_names=[("cam0", "cam1")])] == [
        "x_cam1.png"
    ]


def test_find_pairs_in_a_csv_list(tmp_path: Path) -> None:
    (tmp_path / "imgs").mkdir()
    csv = tmp_path / "pairs.csv"
    csv.write_text(
        "left,right,stem\n# a comment\n\nimgs/a_left.png,imgs/a_right.png,\n"
        f"{tmp_path}/imgs/b0.png,imgs/b1.png,frame-b\n"
    )
    pairs = batch.find_pairs(csv)
    assert [(p.stem, p.left, p.right) for p in pairs] == [
        ("a", tmp_path / "imgs/a_left.png", tmp_path / "imgs/a_right.png"),
        ("frame-b", tmp_path / "imgs/b0.png", tmp_path / "imgs/b1.png"),
    ]
    csv.write_text("a.png,b.png\nc.png\n")
    with pytest.raises(
        batch.UsageError,
        match=r"pairs.csv:2: expected left,right\[,stem\], "
        "got 'c.png'",
    ):
        batch.find_pairs(csv)
    csv.write_text("x/im0.png,x/im1.png\ny/im0.png,y/im1.png,x\n")
    with pytest.raises(batch.UsageError, match="two pairs would write the same outputs 'x'"):
        batch.find_pairs(csv)


def test_find_pairs_rejects(tmp_path: Path) -> None:
    with pytest.raises(batch.UsageError, match="INPUT not found"):
        batch.find_pairs(tmp_path / "absent")
    (tmp_path / "list.txt").write_text("a,b\n")
    with pytest.raises(batch.UsageError, match=r"must be a folder or a \.csv list"):
        batch.find_pairs(tmp_path / "list.txt")
    with pytest.raises(batch.UsageError, match="no stereo pairs found in"):
        batch.find_pairs(tmp_path)


# --- computing --------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", ["npy", "png16", "pfm"])
def test_outputs_equal_the_direct_computation(tmp_path: Path, fmt: str) -> None:
    names = middlebury_folder(tmp_path / "in", 2)
    out = tmp_path / "out"
    assert run_cli("batch", tmp_path / "in", "-o", out, "--format", fmt, "--ply", "--quiet") == 0
    for name in names:
        disparity, depth = expected_maps(tmp_path / "in" / name, fmt)
        if fmt == "npy":
            got_d = np.load(out / f"{name}.disparity.npy")
            got_z = np.load(out / f"{name}.depth.npy")
        elif fmt == "pfm":
            # The disparity in Middlebury's convention, +inf where there is none (a NaN hole
            # is scored as a disparity by its evaldisp): NaN read back by read_disparity_pfm.
            # The depth is a plain PFM (a depth of +inf is disparity 0, a real value).
            raw = io.read_pfm(out / f"{name}.disparity.pfm")
            assert np.array_equal(raw == np.inf, np.isnan(disparity)) and not np.isnan(raw).any()
            got_d, got_z = (
                io.read_disparity_pfm(out / f"{name}.disparity.pfm"),
                io.read_pfm(out / f"{name}.depth.pfm"),
            )
        else:
            got_d, got_z = (
                io.read_image(out / f"{name}.disparity.png"),
                io.read_image(out / f"{name}.depth.png"),
            )
            d64 = disparity.astype(np.float64)
            # KITTI's round(d * 256), half up (the devkit's uint16()), 0 where there is none
            disparity = np.where(np.isfinite(d64) & (d64 > 0), np.floor(d64 * 256 + 0.5), 0).astype(
                np.uint16
            )
        np.testing.assert_array_equal(got_d, disparity, strict=True)
        np.testing.assert_array_equal(got_z, depth, strict=True)
        assert np.isfinite(disparity).mean() > 0.5  # the matcher found the shift
        record = json.loads((out / f"{name}.record.json").read_text())
        assert record["status"] == "ok"
        assert record["density"] == pytest.approx(
            np.count_nonzero(np.isfinite(expected_maps(tmp_path / "in" / name)[0])) / disparity.size
        )
        assert record["outputs"]["ply"]["points"] > 0
        ply = (out / f"{name}.ply").read_bytes()
        assert b"element vertex %d\n" % record["outputs"]["ply"]["points"] in ply
    report = report_of(out)
    assert report["counts"] == {"ok": 2, "skipped": 0, "failed": 0, "cancelled": 0}
    assert report["exit_status"] == 0
    assert [p["stem"] for p in report["pairs"]] == names
    assert temp_files(out) == []


def test_ply_of_12_bit_pairs_is_coloured_as_matched(tmp_path: Path) -> None:
    # 12-bit images in 16-bit PNGs: the points took the high byte of the left image (0..15, a
    # black cloud); they now take its min-max stretch, as the matcher sees it.
    from stereodepth.colormap import to_uint8

    d = tmp_path / "in" / "scene00"
    d.mkdir(parents=True)
    left, right = random_pair(0, 3, rgb=False)
    left16, right16 = left.astype(np.uint16) * 16, right.astype(np.uint16) * 16
    io.write_png16(d / "im0.png", left16)
    io.write_png16(d / "im1.png", right16)
    (d / "calib.txt").write_text(calib_text())
    out = tmp_path / "out"
    assert run_cli("batch", tmp_path / "in", "-o", out, "--ply", "--quiet") == 0
    ply = (out / "scene00.ply").read_bytes()
    body = ply[ply.index(b"end_header\n") + len(b"end_header\n") :]
    rgb = np.frombuffer(body, dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])["rgb"]
    assert len(rgb) > 0 and rgb.max() > 200
    assert set(np.unique(rgb)) <= set(np.unique(to_uint8(left16)))


@pytest.mark.parametrize("fmt", ["npy", "png16"])
def test_preview_writes_the_colour_images_of_both_maps(tmp_path: Path, fmt: str) -> None:
    pytest.importorskip("matplotlib")
    from PIL import Image

    names = middlebury_folder(tmp_path / "in", 1)
    out = tmp_path / "out"
    argv = ("batch", tmp_path / "in", "-o", out, "--format", fmt, "--quiet")
    assert run_cli(*argv, "--preview") == 0
    name = names[0]
    disparity, depth = expected_maps(tmp_path / "in" / name, fmt)
    depth_m = depth if fmt == "npy" else np.where(depth > 0, depth / 1000.0, np.nan)
    record = json.loads((out / f"{name}.record.json").read_text())
    for kind, values in (("disparity", disparity), ("depth", depth_m)):
        path = out / f"{name}.{kind}.preview.png"
        assert record["outputs"][f"{kind}_preview"]["path"] == str(path)
        with Image.open(path) as im:
            assert im.mode == "RGB" and im.width == disparity.shape[1]
            shown = np.asarray(im)[: disparity.shape[0]]
        # The top rows are the colourised map itself; the colour bar is below.
        np.testing.assert_array_equal(shown, stereodepth.colorize(values))
    # A run without --preview is a changed run: it recomputes and removes the stale previews.
    assert run_cli(*argv) == 0
    assert not (out / f"{name}.disparity.preview.png").exists()
    assert not (out / f"{name}.depth.preview.png").exists()


def test_bad_pairs_are_reported_and_the_rest_complete(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    inp = tmp_path / "in"
    names = middlebury_folder(inp, 6)
    data = (inp / names[1] / "im1.png").read_bytes()
    (inp / names[1] / "im1.png").write_bytes(data[: len(data) // 3])  # corrupt
    (inp / names[2] / "im1.png").unlink()  # missing right image
    small = random_pair(9, 3, shape=(40, 64))[1]
    Image.fromarray(small).save(inp / names[3] / "im1.png")  # size mismatch
    (inp / names[4] / "calib.txt").write_text("cam0=[1 2 3]\nbaseline=1\n")  # bad calibration
    out = tmp_path / "out"
    assert run_cli("batch", inp, "-o", out) == 1
    report = report_of(out)
    status = {p["stem"]: (p["status"], p["error"]) for p in report["pairs"]}
    assert status[names[0]] == ("ok", None) and status[names[5]] == ("ok", None)
    assert status[names[1]][0] == "failed" and "cannot decode image" in status[names[1]][1]
    assert status[names[2]][0] == "failed"
    assert status[names[2]][1] == f"missing right image {inp / names[2] / 'im1.png'}"
    assert status[names[3]] == ("failed", "left and right differ in size: 64x48 and 64x40 px")
    assert "bad calibration" in status[names[4]][1] and "cam0 must be a 3x3" in status[names[4]][1]
    assert report["counts"] == {"ok": 2, "skipped": 0, "failed": 4, "cancelled": 0}
    assert report["exit_status"] == 1
    printed = capsys.readouterr().out
    assert "6 pairs: 2 done, 4 failed" in printed
    for n in names[1:5]:
        assert f"failed {n}:" in printed
        # a failed pair leaves its record, which says so, and no output
        assert [p.name for p in out.glob(f"{n}.*")] == [f"{n}.record.json"]
        assert json.loads((out / f"{n}.record.json").read_text())["status"] == "failed"
    for n in (names[0], names[5]):
        assert (out / f"{n}.depth.npy").is_file() and (out / f"{n}.record.json").is_file()
    # fix the missing image: the next run does that pair only
    Image.fromarray(random_pair(2, 4)[1]).save(inp / names[2] / "im1.png")
    assert run_cli("batch", inp, "-o", out, "--quiet") == 1
    counts = report_of(out)["counts"]
    assert counts == {"ok": 1, "skipped": 2, "failed": 3, "cancelled": 0}


def test_a_colour_and_a_grey_image_are_refused_as_block_match_does(tmp_path: Path) -> None:
    """One rule for batch and block_match: both images colour or both grey. block_match
    raises; batch fails the pair with a message saying which image is which."""
    left, right = random_pair(5, 3)
    grey_right = right[..., 1].copy()
    with pytest.raises((TypeError, ValueError)):
        stereodepth.block_match(left, grey_right, num_disparities=16)
    Image.fromarray(left).save(tmp_path / "left.png")
    Image.fromarray(grey_right).save(tmp_path / "right.png")
    out = tmp_path / "out"
    argv = ["--focal-px", 700, "--baseline-mm", 100, "--num-disparities", 16, "--quiet"]
    assert run_cli("batch", tmp_path, "-o", out, *argv) == 1
    rec = report_of(out)["pairs"][0]
    assert rec["status"] == "failed"
    assert rec["error"] == (
        "the left image is colour (RGB) and the right image grey: both must be colour or both "
        "grey (convert one of them; block_match refuses a mixed pair too)"
    )
    assert not (out / f"{tmp_path.name}.disparity.npy").exists()


def test_resume_skips_complete_pairs_and_redoes_changed_ones(tmp_path: Path) -> None:
    inp, out = tmp_path / "in", tmp_path / "out"
    names = middlebury_folder(inp, 3)
    assert run_cli("batch", inp, "-o", out, "--quiet") == 0
    first = outputs_bytes(out)
    assert run_cli("batch", inp, "-o", out, "--quiet") == 0
    assert report_of(out)["counts"]["skipped"] == 3
    skipped = report_of(out)["pairs"][0]
    assert skipped["status"] == "skipped" and skipped["density"] > 0.5
    # an output deleted, an input rewritten: those two pairs are redone
    (out / f"{names[0]}.depth.npy").unlink()
    left = io.read_image(inp / names[1] / "im0.png")
    Image.fromarray(left).save(inp / names[1] / "im0.png")
    os.utime(inp / names[1] / "im0.png", ns=(1, 1))
    assert run_cli("batch", inp, "-o", out, "--quiet") == 0
    assert [p["status"] for p in report_of(out)["pairs"]] == ["ok", "ok", "skipped"]
    assert outputs_bytes(out) == first
    # different settings: everything is redone; --force redoes it again
    assert run_cli("batch", inp, "-o", out, "--quiet", "--block-size", "7") == 0
    assert report_of(out)["counts"]["ok"] == 3
    assert run_cli("batch", inp, "-o", out, "--quiet", "--block-size", "7") == 0
    assert report_of(out)["counts"]["skipped"] == 3
    assert run_cli("batch", inp, "-o", out, "--quiet", "--block-size", "7", "--force") == 0
    assert report_of(out)["counts"]["ok"] == 3
    # a calibration edited to another image size than the pair's: refused, as on a first run
    # (it was "already done": the size was not among the settings compared)
    calib = inp / names[2] / "calib.txt"
    calib.write_text(calib_text().replace(f"width={SHAPE[1]}", f"width={2 * SHAPE[1]}"))
    assert run_cli("batch", inp, "-o", out, "--quiet", "--block-size", "7") == 1
    pairs = report_of(out)["pairs"]
    assert [p["status"] for p in pairs] == ["skipped", "skipped", "failed"]
    assert "a calibration of another resolution gives wrong depths" in pairs[2]["error"]


# --- interruptions ----------------------------------------------------------------------------
# Dask may run a preload file twice in one module namespace: keep the original compute.
SLOW_MATCHER = """
import time
from stereodepth import matching
_compute = getattr(matching.StereoMatcher.compute, "__wrapped__", matching.StereoMatcher.compute)
def _slow(self, left, right):
    time.sleep({delay})
    return _compute(self, left, right)
_slow.__wrapped__ = _compute
matching.StereoMatcher.compute = _slow
"""


def cli_process(argv: list[str], prelude: str) -> subprocess.Popen[str]:
    script = (
        prelude + "\nimport sys\nfrom stereodepth import cli\n" + f"sys.exit(cli.main({argv!r}))\n"
    )
    return subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def killed_at(argv: list[str], prelude: str, line: str) -> subprocess.Popen[str]:
    """``stereodepth`` run with ``argv`` under ``prelude`` in a process of its own, killed
    (SIGKILL) once it prints ``line``; returns the ended process."""
    with cli_process(argv, prelude) as proc:
        try:
            assert proc.stdout is not None
            assert proc.stdout.readline().strip() == line
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.communicate(timeout=60)
    return proc


def hang_on_depth(stem: str) -> str:
    """A prelude under which writing pair ``stem``'s depth (.npy) prints "writing the depth"
    and hangs: its disparity is written, its depth and record not."""
    return f"""
import os, time
from stereodepth import io
_write_npy = io.write_npy
def _hang_on_the_depth(path, array):
    if os.path.basename(str(path)) == "{stem}.depth.npy":
        print("writing the depth", flush=True)
        time.sleep(120)
    return _write_npy(path, array)
io.write_npy = _hang_on_the_depth
"""


def run_cli_in(argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """``stereodepth`` run with ``argv`` in a process of its own from ``cwd`` (relative paths
    as a user in that folder types them), its output captured."""
    return subprocess.run(
        [
            sys.executable,
            "-c",
            f"import sys; from stereodepth import cli; sys.exit(cli.main({argv!r}))",
        ],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )


def wait_for(predicate: Any, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError("condition not met in time")
        time.sleep(0.02)


def test_ctrl_c_stops_cleanly_and_the_next_run_resumes(tmp_path: Path) -> None:
    inp, out = tmp_path / "in", tmp_path / "out"
    names = middlebury_folder(inp, 12)
    with cli_process(["batch", str(inp), "-o", str(out)], SLOW_MATCHER.format(delay=0.3)) as proc:
        try:
            wait_for(lambda: out.is_dir() and any(out.glob("*.record.json")))
        finally:
            proc.send_signal(signal.SIGINT)
            stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr
    assert "run the same command again to resume" in stdout
    report = report_of(out)
    counts = report["counts"]
    assert report["interrupted"] and report["exit_status"] == 130
    assert counts["ok"] >= 1 and counts["cancelled"] >= 1 and counts["failed"] == 0
    assert counts["ok"] + counts["cancelled"] == 12
    assert temp_files(out) == []
    done = [p["stem"] for p in report["pairs"] if p["status"] == "ok"]
    records = sorted(p.name.removesuffix(".record.json") for p in out.glob("*.record.json"))
    assert records == sorted(done)
    assert run_cli("batch", inp, "-o", out, "--quiet") == 0
    again = report_of(out)["counts"]
    assert again == {"ok": 12 - len(done), "skipped": len(done), "failed": 0, "cancelled": 0}
    for name in names:
        np.testing.assert_array_equal(
            np.load(out / f"{name}.depth.npy"), expected_maps(inp / name)[1], strict=True
        )


def test_an_interrupted_forced_run_reports_what_it_did_not_redo_as_cancelled(
    tmp_path: Path,
) -> None:
    # --force redoes every pair; when it was interrupted, the pairs it never reached were
    # reported "ok" (with the time of the run before), as their old complete records said.
    inp, out = tmp_path / "in", tmp_path / "out"
    middlebury_folder(inp, 8)
    pairs = batch.resolve_calibration(batch.find_pairs(inp))
    first = batch.run_batch(pairs, batch.BatchOptions(out_dir=out))
    assert first.counts["ok"] == 8
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("*.record.json")}

    def stop(record: dict[str, Any]) -> None:
        raise KeyboardInterrupt

    report = batch.run_batch(pairs, batch.BatchOptions(out_dir=out, force=True), on_result=stop)
    assert report.interrupted
    redone = {
        p.name.removesuffix(".record.json")
        for p in out.glob("*.record.json")
        if p.stat().st_mtime_ns != before[p.name]
    }
    statuses = {r["stem"]: r["status"] for r in report.pairs}
    assert 1 <= len(redone) < 8
    assert {s for s, st in statuses.items() if st == "ok"} == redone
    assert {s for s, st in statuses.items() if st == "cancelled"} == set(statuses) - redone
    # "run the same command again to resume": with --force that starts over, and without it
    # the pairs not reached are skipped (their earlier outputs are complete)
    assert report.as_dict()["force"] is True
    text = io_module.StringIO()
    batch.print_summary(report, out / "report.json", file=text)
    assert "interrupted: --force redoes every pair, so the same command starts over" in (
        text.getvalue()
    )
    assert "run the same command again to resume" not in text.getvalue()


def test_pairs_an_interrupted_job_never_started_are_cancelled_not_ok(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Ctrl-C while the job was still checking which pairs were done: the pairs it had not
    # looked at yet were reported "ok" from the run before's records, though it ran none.
    inp, out = tmp_path / "in", tmp_path / "out"
    middlebury_folder(inp, 3)
    pairs = batch.resolve_calibration(batch.find_pairs(inp))
    assert batch.run_batch(pairs, batch.BatchOptions(out_dir=out)).counts["ok"] == 3
    real = batch.runners.completed_record
    calls = []

    def interrupted_at_the_second(pair: Any, options: Any) -> Any:
        calls.append(pair.stem)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(pair, options)

    monkeypatch.setattr(batch.runners, "completed_record", interrupted_at_the_second)
    report = batch.run_batch(pairs, batch.BatchOptions(out_dir=out))
    assert report.interrupted
    assert [r["status"] for r in report.pairs] == ["skipped", "cancelled", "cancelled"]


HALF_WRITE = """
import os, sys, time
import numpy as np
from stereodepth import io
_write_npy = io.write_npy
def _half_then_hang(path, array):
    if os.path.basename(str(path)) == "scene03.depth.npy":
        import io as _io
        buf = _io.BytesIO()
        np.save(buf, array)
        with io.atomic_write(path) as f:
            f.write(buf.getvalue()[: len(buf.getvalue()) // 2])
            f.flush()
            print("half written", flush=True)
            time.sleep(120)
    return _write_npy(path, array)
io.write_npy = _half_then_hang
"""


def test_kill_leaves_no_partial_file_and_the_next_run_completes(tmp_path: Path) -> None:
    inp, out = tmp_path / "in", tmp_path / "out"
    names = middlebury_folder(inp, 6)
    proc = killed_at(["batch", str(inp), "-o", str(out)], HALF_WRITE, "half written")
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "scene03.depth.npy").exists()
    # the half-written file (and whatever the other pair in flight was writing) as temporaries
    left_over = temp_files(out)
    assert any(t.startswith(".scene03.depth.npy.stereodepth-") for t in left_over)
    assert all(t.startswith(".") and ".stereodepth-" in t for t in left_over)
    # everything under a final name is complete; the pairs in flight have the record written
    # before their first file (status "started", listing their files), the others none
    statuses = {
        p.name.removesuffix(".record.json"): json.loads(p.read_text())["status"]
        for p in out.glob("*.record.json")
    }
    assert statuses["scene03"] == "started"
    assert set(statuses.values()) <= {"ok", "started"}
    records = {stem for stem, status in statuses.items() if status == "ok"}
    for f in out.glob("*.npy"):
        stem, kind = f.name.split(".")[:2]
        want = expected_maps(inp / stem)[0 if kind == "disparity" else 1]
        np.testing.assert_array_equal(np.load(f), want, strict=True)
    for stem in records:
        assert (out / f"{stem}.disparity.npy").is_file() and (out / f"{stem}.depth.npy").is_file()
    # the next run sweeps the temporary file and does what is left
    assert run_cli("batch", inp, "-o", out, "--quiet") == 0
    counts = report_of(out)["counts"]
    assert counts["skipped"] == len(records) and counts["ok"] == 6 - len(records)
    assert temp_files(out) == []
    for name in names:
        np.testing.assert_array_equal(
            np.load(out / f"{name}.depth.npy"), expected_maps(inp / name)[1], strict=True
        )


def test_a_second_job_on_the_same_outdir_is_refused(tmp_path: Path) -> None:
    inp, out = tmp_path / "in", tmp_path / "out"
    middlebury_folder(inp, 1)
    out.mkdir()
    import fcntl

    fd = os.open(out / batch.LOCK_NAME, os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        with pytest.raises(batch.UsageError, match="another stereodepth batch job is writing"):
            batch.run_batch(
                batch.resolve_calibration(batch.find_pairs(inp)), batch.BatchOptions(out_dir=out)
            )
    finally:
        os.close(fd)


# --- usage errors -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("extra", "calib", "message"),
    [
        ([], False, "no calibration for any pair: give --focal-px and --baseline-mm"),
        (["--focal-px", "700"], False, "give both --focal-px and --baseline-mm"),
        (["--focal-px", "700", "--baseline-mm", "100"], False, "--num-disparities is required"),
        (
            ["--focal-px", "-7", "--baseline-mm", "100"],
            False,
            "--focal-px must be a finite number > 0, got -7.0",
        ),
        (["--cx-px", "3"], True, "--cx-px goes with --focal-px and --baseline-mm"),
        (
            ["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
            True,
            "give --scheduler or --workers, not both",
        ),
        (["--workers", "0"], True, "--workers must be an integer >= 1, got 0"),
        (["--block-size", "4"], True, "block_size must be an odd integer"),
        (
            ["--option", "num_disparities=4"],
            True,
            "--option num_disparities: use --num-disparities",
        ),
        (
            ["--option", "colour=1"],
            True,
            "--option colour: --method bm \\(block matching\\) has no option 'colour'",
        ),
        (["--num-disparities", "0"], True, "--num-disparities must be an integer >= 1, got 0"),
        (["--max-depth-m", "nan"], True, "--max-depth-m must be a finite number > 0, got nan"),
        (["--calib", "nowhere.txt"], True, "--calib: calibration file not found"),
    ],
)
def test_usage_errors_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], calib: bool, message: str
) -> None:
    left, right = random_pair(0, 2)
    Image.fromarray(left).save(tmp_path / "im0.png")
    Image.fromarray(right).save(tmp_path / "im1.png")
    if calib:
        (tmp_path / "calib.txt").write_text(calib_text())
    assert run_cli("batch", tmp_path, "-o", tmp_path / "out", *extra) == 2
    err = capsys.readouterr().err
    assert err.startswith("stereodepth batch: error: ")
    import re

    assert re.search(message, err), err
    assert not (tmp_path / "out").exists()


# --- a real Dask cluster ----------------------------------------------------------------------
@pytest.fixture
def local_cluster() -> Any:
    distributed = pytest.importorskip("distributed")
    # dashboard_address: a free loopback port (None would still try 8787, and warn if taken)
    with distributed.LocalCluster(
        n_workers=2,
        processes=True,
        threads_per_worker=1,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
    ) as cluster:
        yield cluster


@contextlib.contextmanager
def in_process_cluster() -> Iterator[Any]:
    """A one-worker Dask cluster in this process, on loopback TCP: its worker works in this
    process's folder, and a job sent to it by address from another process sees the paths
    that process sends."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=1,
        processes=False,
        protocol="tcp",
        threads_per_worker=1,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
    ) as cluster:
        yield cluster


@pytest.mark.cluster
def test_cluster_results_equal_embedded_bit_for_bit(tmp_path: Path, local_cluster: Any) -> None:
    inp = tmp_path / "in"
    middlebury_folder(inp, 6)
    assert run_cli("batch", inp, "-o", tmp_path / "here", "--ply", "--quiet") == 0
    assert (
        run_cli(
            "batch",
            inp,
            "-o",
            tmp_path / "there",
            "--ply",
            "--quiet",
            "--scheduler",
            local_cluster.scheduler_address,
        )
        == 0
    )
    report = report_of(tmp_path / "there")
    assert report["runner"] == f"dask {local_cluster.scheduler_address}"
    assert report["counts"]["ok"] == 6
    here, there = outputs_bytes(tmp_path / "here"), outputs_bytes(tmp_path / "there")
    assert len(here) == 18 and here == there


@pytest.mark.cluster
def test_a_worker_killed_mid_job_and_the_job_completes(tmp_path: Path, local_cluster: Any) -> None:
    distributed = pytest.importorskip("distributed")
    inp = tmp_path / "in"
    n = 10
    middlebury_folder(inp, n)
    assert run_cli("batch", inp, "-o", tmp_path / "here", "--quiet") == 0
    pairs = batch.resolve_calibration(batch.find_pairs(inp))
    killed: list[str] = []
    with distributed.Client(local_cluster.scheduler_address) as client:
        client.run(exec, SLOW_MATCHER.format(delay=0.4), {})  # each pair takes >= 0.4 s
        pids = client.run(os.getpid)

        def kill_a_busy_worker(record: dict[str, Any]) -> None:
            if killed:
                return
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:  # a worker between two pairs is not busy
                busy = [w for w, keys in client.processing().items() if keys]
                if busy:
                    os.kill(pids[busy[0]], signal.SIGKILL)
                    killed.append(busy[0])
                    return
                time.sleep(0.01)

        report = batch.run_batch(
            pairs,
            batch.BatchOptions(out_dir=tmp_path / "there"),
            scheduler=local_cluster.scheduler_address,
            on_result=kill_a_busy_worker,
        )
    assert killed
    assert report.counts == {"ok": n, "skipped": 0, "failed": 0, "cancelled": 0}
    assert outputs_bytes(tmp_path / "there") == outputs_bytes(tmp_path / "here")
    assert temp_files(tmp_path / "there") == []


@pytest.mark.cluster
def test_relative_paths_reach_a_scheduler_whose_workers_work_elsewhere(tmp_path: Path) -> None:
    # INPUT and OUTDIR given relative to the command's folder were sent to the cluster as
    # they were: a worker in another folder found no images (every pair failed) or would
    # have written the outputs into its own folder.
    middlebury_folder(tmp_path / "in", 2)
    assert Path.cwd() != tmp_path  # the workers below run in this process, in its folder
    with in_process_cluster() as cluster:
        argv = ["batch", "in", "-o", "out", "--quiet", "--scheduler", cluster.scheduler_address]
        proc = run_cli_in(argv, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    report = report_of(tmp_path / "out")
    assert report["counts"]["ok"] == 2
    for name in ("scene00", "scene01"):
        np.testing.assert_array_equal(
            np.load(tmp_path / "out" / f"{name}.depth.npy"),
            expected_maps(tmp_path / "in" / name)[1],
            strict=True,
        )


def test_the_same_job_with_input_spelled_otherwise_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A pair's record named its images by the path as given, so the same job run again with
    INPUT absolute instead of relative (or from another folder) redid every pair."""
    middlebury_folder(tmp_path / "in", 2)
    monkeypatch.chdir(tmp_path)
    assert run_cli("batch", "in", "-o", "out", "--quiet") == 0
    stamps = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "out").glob("*.npy")}
    assert run_cli("batch", tmp_path / "in", "-o", tmp_path / "out", "--quiet") == 0
    assert report_of(tmp_path / "out")["counts"]["skipped"] == 2
    monkeypatch.chdir(tmp_path / "in")
    assert run_cli("batch", ".", "-o", "../out", "--quiet") == 0
    assert report_of(tmp_path / "out")["counts"]["skipped"] == 2
    assert {p.name: p.stat().st_mtime_ns for p in (tmp_path / "out").glob("*.npy")} == stamps
    # an image changed is still redone
    (tmp_path / "in" / "scene01" / "im1.png").write_bytes(
        (tmp_path / "in" / "scene00" / "im1.png").read_bytes()
    )
    assert run_cli("batch", "scene01", "-o", "../out", "--quiet") == 0
    assert [p["status"] for p in report_of(tmp_path / "out")["pairs"]] == ["ok"]


def test_a_second_job_whose_stems_repeat_the_first_does_not_replace_its_results(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two jobs into one OUTDIR whose pairs share stems (KITTI 2012's and 2015's training
    frames are both 000000_10...): the second replaced the first's results without a word
    (exit 0, '2 done'). Refused before any pair, one line naming both images; --force
    replaces them."""
    middlebury_folder(tmp_path / "first", 2)
    middlebury_folder(tmp_path / "second", 2, first_seed=7)
    out = tmp_path / "out"
    assert run_cli("batch", tmp_path / "first", "-o", out, "--quiet") == 0
    before = outputs_bytes(out)
    capsys.readouterr()
    assert run_cli("batch", tmp_path / "second", "-o", out, "--quiet") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("stereodepth batch: error: OUTDIR "), err
    left = (tmp_path / "first" / "scene00" / "im0.png").resolve()
    assert f"holds the outputs of pair 'scene00' made from other images ({left}, " in err
    assert "give --force to replace them" in err
    assert outputs_bytes(out) == before
    assert report_of(out)["counts"]["ok"] == 2  # the first job's report, untouched
    # the first job's own run again is no collision, and --force replaces
    assert run_cli("batch", tmp_path / "first", "-o", out, "--quiet") == 0
    assert run_cli("batch", tmp_path / "second", "-o", out, "--quiet", "--force") == 0
    for name in ("scene00", "scene01"):
        disparity, depth = expected_maps(tmp_path / "second" / name)
        np.testing.assert_array_equal(np.load(out / f"{name}.disparity.npy"), disparity)
        np.testing.assert_array_equal(np.load(out / f"{name}.depth.npy"), depth)


@pytest.mark.cluster
def test_a_job_of_a_scheduler_resumes_here(tmp_path: Path) -> None:
    """A --scheduler job (its paths made absolute for the workers) resumed in this process
    after the cluster went away, with the same relative INPUT: every pair was redone."""
    middlebury_folder(tmp_path / "in", 2)
    argv = ["batch", "in", "-o", "out", "--quiet"]
    with in_process_cluster() as cluster:
        code = [*argv, "--scheduler", cluster.scheduler_address]
        proc = run_cli_in(code, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert report_of(tmp_path / "out")["counts"]["ok"] == 2
    proc = run_cli_in(argv, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert report_of(tmp_path / "out")["counts"] == {
        "ok": 0, "skipped": 2, "failed": 0, "cancelled": 0,
    }  # fmt: skip


@pytest.mark.cluster
def test_a_scheduler_address_with_a_trailing_slash_reaches_it(tmp_path: Path) -> None:
    # --scheduler tcp://HOST:PORT/ passes the address check (as a URL's may end), and was then
    # handed to Dask as it was: "what answered there is not a Dask scheduler (ValueError:
    # invalid literal for int() with base 10: '8786/')", exit 2, with a scheduler there.
    middlebury_folder(tmp_path / "in", 2)
    with in_process_cluster() as cluster:
        address = cluster.scheduler_address + "/"
        argv = ["batch", "in", "-o", "out", "--quiet", "--scheduler", address]
        proc = run_cli_in(argv, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    report = report_of(tmp_path / "out")
    assert report["counts"]["ok"] == 2
    assert report["runner"] == f"dask {cluster.scheduler_address}"


@pytest.mark.cluster
def test_workers_option_starts_a_local_cluster(tmp_path: Path) -> None:
    pytest.importorskip("distributed")
    inp = tmp_path / "in"
    middlebury_folder(inp, 3)
    assert run_cli("batch", inp, "-o", tmp_path / "here", "--quiet") == 0
    assert run_cli("batch", inp, "-o", tmp_path / "there", "--quiet", "--workers", "2") == 0
    assert report_of(tmp_path / "there")["runner"] == "local dask cluster of 2 worker processes"
    assert outputs_bytes(tmp_path / "there") == outputs_bytes(tmp_path / "here")


def test_on_result_runs_in_the_calling_thread(tmp_path: Path) -> None:
    inp = tmp_path / "in"
    middlebury_folder(inp, 3)
    seen: list[tuple[str, int]] = []
    report = batch.run_batch(
        batch.resolve_calibration(batch.find_pairs(inp)),
        batch.BatchOptions(out_dir=tmp_path / "out"),
        on_result=lambda r: seen.append((r["status"], threading.get_ident())),
    )
    assert sorted(s for s, _ in seen) == ["ok"] * 3
    assert {t for _, t in seen} == {threading.get_ident()}
    assert report.exit_status == 0


def test_progress_bar_and_summary(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    inp = tmp_path / "in"
    middlebury_folder(inp, 3)
    report = batch.run_batch(
        batch.resolve_calibration(batch.find_pairs(inp)),
        batch.BatchOptions(out_dir=tmp_path / "out"),
        progress=True,
    )
    err = capsys.readouterr().err
    assert "stereodepth batch" in err and "3/3" in err
    batch.print_summary(report, tmp_path / "out" / "report.json")
    out = capsys.readouterr().out
    assert out.startswith("3 pairs: 3 done in ") and "pairs/s, embedded)" in out


def test_ctrl_c_during_a_dask_job_sets_a_flag_and_a_second_one_raises() -> None:
    """While a Dask job runs, the first SIGINT only sets the runner's stop flag (Dask's blocking
    calls are not safe to interrupt); a second one raises KeyboardInterrupt; the default handler
    comes back afterwards. A handler the application installed is left alone."""
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with batch.runners._sigint_as_flag() as stop:
        assert not stop.is_set()
        signal.raise_signal(signal.SIGINT)
        assert stop.is_set()
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler

    seen: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: seen.append(signum))
    try:
        with batch.runners._sigint_as_flag() as stop:
            signal.raise_signal(signal.SIGINT)
            assert not stop.is_set() and seen == [signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, previous)


def ctrl_c_batch(inp: Path, out: Path, preload: Path, workers: str, ready: Any) -> tuple[int, str]:
    """``stereodepth batch INP -o OUT --workers N`` in a process group of its own, with
    ``preload`` run by dask in each worker; once ``ready()`` holds, SIGINT to the whole group
    (a terminal's Ctrl-C). Returns the exit status and stderr."""
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__PRELOAD": json.dumps([str(preload)])}
    argv = [sys.executable, "-m", "stereodepth.cli", "batch", str(inp), "-o", str(out)]
    with subprocess.Popen(
        [*argv, "--workers", workers],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    ) as proc:
        try:
            wait_for(ready, timeout=120)
        finally:
            os.killpg(proc.pid, signal.SIGINT)
            _, stderr = proc.communicate(timeout=120)
    return proc.returncode, stderr


@pytest.mark.cluster
def test_ctrl_c_while_the_local_cluster_starts_stops_the_job(tmp_path: Path) -> None:
    """SIGINT is ignored while the worker processes start (so that they inherit it ignored),
    and a Ctrl-C in those seconds was lost: the job ran every pair and ended with status 0.
    Now it stops before any pair, status 130, every pair cancelled. The workers' start is
    slowed down through dask's worker preload hook."""
    pytest.importorskip("distributed")
    inp, out = tmp_path / "in", tmp_path / "out"
    middlebury_folder(inp, 3)
    marker = tmp_path / "worker-starting"
    preload = tmp_path / "slow_start.py"
    preload.write_text(
        f"import pathlib, time\npathlib.Path({str(marker)!r}).touch()\ntime.sleep(3)\n"
    )
    status, stderr = ctrl_c_batch(inp, out, preload, "1", ready=marker.exists)
    assert status == 130, stderr
    assert "Traceback" not in stderr, stderr
    report = report_of(out)
    assert report["interrupted"]
    assert report["counts"] == {"ok": 0, "skipped": 0, "failed": 0, "cancelled": 3}
    assert sorted(p.name for p in out.iterdir()) == ["report.json"]
    # and the same command then does the job
    assert run_cli("batch", inp, "-o", out, "--quiet") == 0
    for name in ("scene00", "scene01", "scene02"):
        np.testing.assert_array_equal(
            np.load(out / f"{name}.depth.npy"), expected_maps(inp / name)[1], strict=True
        )


@pytest.mark.cluster
def test_ctrl_c_in_a_terminal_with_local_workers(tmp_path: Path) -> None:
    """Ctrl-C reaches the whole process group: the job stops with status 130 and a report,
    the worker processes (which ignore SIGINT) print no tracebacks, no temporary file is
    left. The workers are slowed down through dask's worker preload hook."""
    pytest.importorskip("distributed")
    inp, out = tmp_path / "in", tmp_path / "out"
    middlebury_folder(inp, 12)
    preload = tmp_path / "slow_worker.py"
    preload.write_text(SLOW_MATCHER.format(delay=0.5))
    status, stderr = ctrl_c_batch(
        inp, out, preload, "2", ready=lambda: out.is_dir() and any(out.glob("scene*.json"))
    )
    assert status == 130, stderr
    assert "Traceback" not in stderr, stderr
    assert "interrupted" in stderr
    report = report_of(out)
    assert report["interrupted"] and report["counts"]["cancelled"] >= 1
    assert report["counts"]["ok"] >= 1 and report["counts"]["failed"] == 0
    assert temp_files(out) == []


def test_non_ascii_names_and_a_csv_list(tmp_path: Path) -> None:
    left, right = random_pair(8, 3)
    (tmp_path / "façade").mkdir()
    Image.fromarray(left).save(tmp_path / "façade" / "gauche.png")
    Image.fromarray(right).save(tmp_path / "façade" / "droite.png")
    (tmp_path / "pairs.csv").write_text(
        "façade/gauche.png,façade/droite.png,vue-été\n", encoding="utf-8"
    )
    out = tmp_path / "out"
    assert (
        run_cli(
            "batch",
            tmp_path / "pairs.csv",
            "-o",
            out,
            "--focal-px",
            700,
            "--baseline-mm",
            100,
            "--num-disparities",
            16,
            "--ply",
            "--quiet",
        )
        == 0
    )
    assert (out / "vue-été.ply").read_bytes().count(b"comment stereodepth") == 1
    assert report_of(out)["pairs"][0]["stem"] == "vue-été"


def test_a_pair_redone_with_other_settings_and_killed_is_not_taken_for_done(
    tmp_path: Path,
) -> None:
    # A finished pair redone with other settings kept the run before's "ok" record until its
    # own: killed between its disparity and its depth, it left the new disparity beside the
    # old depth, and the next run with the first settings said "already done" (the record
    # compares the files' sizes, the same for both). The record written before the first file
    # now replaces the old one, so the pair is redone.
    inp, out = tmp_path / "in", tmp_path / "out"
    middlebury_folder(inp, 1)
    assert run_cli("batch", inp, "-o", out, "--quiet") == 0
    argv = ["batch", str(inp), "-o", str(out), "--quiet", "--option", "uniqueness_ratio=40"]
    killed_at(argv, hang_on_depth("scene00"), "writing the depth")
    assert json.loads((out / "scene00.record.json").read_text())["status"] == "started"
    assert run_cli("batch", inp, "-o", out, "--quiet") == 0
    assert report_of(out)["counts"]["ok"] == 1  # redone, not skipped
    disparity, depth = expected_maps(inp / "scene00")
    np.testing.assert_array_equal(np.load(out / "scene00.disparity.npy"), disparity, strict=True)
    np.testing.assert_array_equal(np.load(out / "scene00.depth.npy"), depth, strict=True)


def test_a_workers_address_given_as_the_scheduler_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A worker speaks Dask's protocol, so the handshake passed, and the Client's own error
    # came out as it was: "Worker.identity() got an unexpected keyword argument 'n_workers'".
    inp, out = tmp_path / "in", tmp_path / "out"
    middlebury_folder(inp, 1)
    with in_process_cluster() as cluster:
        worker = next(iter(cluster.scheduler_info["workers"]))
        status = run_cli("batch", inp, "-o", out, "--quiet", "--scheduler", worker)
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.count("\n") == 1, err
    assert err.startswith(
        f"stereodepth batch: error: --scheduler {worker!r}: what answered there speaks Dask's "
        "protocol but is not a scheduler (a worker's address?)"
    ), err
    assert not out.exists()
