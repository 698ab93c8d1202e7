"""``stereodepth batch --calib RAW``: a calibration of raw (unrectified) pairs makes batch rectify
every pair before matching, by the rule of ``stereodepth match`` (one shared helper). The raw
pairs come from the generator of test_rectify_roundtrip.py (through test_match_rectify.py's
``raw_files``), the calibration files are written by test_match_rectify.py's writers (OpenCV
FileStorage YAML, skipped without OpenCV; ROS camera_info). Each pair's disparity must be the
matcher's of ``StereoRectifier.rectify`` of the raw pair, and its depth ``disparity_to_depth``
with ``rectifier.rig``, bit for bit, here and on a real Dask LocalCluster; the bad inputs are
one line with exit status 2."""

from __future__ import annotations

import importlib.util
import json
import pickle
import types
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

pytest.importorskip("PIL", reason="reading images needs Pillow (the batch extra)")

import stereodepth
from stereodepth import batch, cli, io
from stereodepth.calib import read_stereo_calibration
from stereodepth.rectify import StereoRectifier
from stereodepth.sample import sample_pair


def _load(name: str) -> ModuleType:
    """A test file of this folder as a module, for its documented helpers (pytest imports
    test files with importlib, so they cannot import each other by name)."""
    path = Path(__file__).with_name(name)
    spec = importlib.util.spec_from_file_location(f"_helpers_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


mr = _load("test_match_rectify.py")
tb = _load("test_batch.py")
NDISP = 16


def raw_folder(root: Path, n: int = 2) -> tuple[Path, Any]:
    """``n`` raw pairs in ``root/in/p<i>/left.png, right.png`` (the same camera rig, other
    scenes); returns the folder and the generator's calibration."""
    calib = None
    for i in range(n):
        d = root / "in" / f"p{i}"
        d.mkdir(parents=True)
        s = sample_pair(96, 64, seed=i)
        left, right, calib = mr.raw_files(d, s.left, s.right)
        left.rename(d / "left.png")
        right.rename(d / "right.png")
    return root / "in", calib


def expected(
    left: Path, right: Path, rect: StereoRectifier, method: str = "bm"
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The library's steps by hand: rectify, match, depth with the rectifier's rig."""
    rect_l, rect_r = rect.rectify(io.read_image(left), io.read_image(right))
    match = stereodepth.block_match if method == "bm" else stereodepth.semi_global_match
    disparity = match(rect_l, rect_r, num_disparities=NDISP)
    assert isinstance(disparity, np.ndarray)
    rig = rect.rig
    depth = stereodepth.disparity_to_depth(
        disparity, focal_px=rig.focal_px, baseline_m=rig.baseline_mm / 1000, doffs_px=rig.doffs_px
    )
    return disparity, depth, rect_l, rect_r


def run_cli(*argv: str | Path) -> int:
    return cli.main([str(a) for a in argv])


@pytest.mark.parametrize("method", ["bm", "sgm"])
def test_raw_opencv_yaml_rectifies_every_pair(tmp_path: Path, method: str) -> None:
    inp, calib = raw_folder(tmp_path, 2)
    yaml = mr.write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=False)
    out = tmp_path / "out"
    status = run_cli(
        "batch", inp, "-o", out, "--calib", yaml, "--translation-unit", "mm",
        "--num-disparities", NDISP, "--method", method, "--write-rectified", "--ply", "--quiet",
    )  # fmt: skip
    assert status == 0
    rect = StereoRectifier.from_calibration(read_stereo_calibration(yaml, translation_unit="mm"))
    rig = rect.rig
    assert rig.baseline_mm == pytest.approx(100.0, rel=1e-9)
    for stem in ("p0", "p1"):
        disparity, depth, rect_l, rect_r = expected(
            inp / stem / "left.png", inp / stem / "right.png", rect, method
        )
        np.testing.assert_array_equal(
            np.load(out / f"{stem}.disparity.npy"), disparity, strict=True
        )
        np.testing.assert_array_equal(np.load(out / f"{stem}.depth.npy"), depth, strict=True)
        np.testing.assert_array_equal(io.read_image(out / f"{stem}.left-rectified.png"), rect_l)
        np.testing.assert_array_equal(io.read_image(out / f"{stem}.right-rectified.png"), rect_r)
        assert np.isfinite(disparity).mean() > 0.5
        record = json.loads((out / f"{stem}.record.json").read_text())
        assert record["status"] == "ok" and record["rectified"] is True
        assert record["method"] == method
        assert record["calibration_source"] == f"--calib {yaml} (rectified)"
        settings = record["settings"]
        assert settings["rectification"]["calibration"] == str(yaml)
        assert settings["rectification"]["rectified_size"] == [96, 64]
        assert settings["calibration"]["focal_px"] == rig.focal_px
        assert settings["calibration"]["baseline_m"] == rig.baseline_mm / 1000
        assert settings["calibration"]["cx_px"] == float(rect.P1[0, 2])
        assert settings["calibration"]["cy_px"] == float(rect.P1[1, 2])
        assert record["outputs"]["ply"]["points"] > 0
        assert set(record["outputs"]) >= {"left_rectified", "right_rectified"}
    report = tb.report_of(out)
    assert report["rectification"]["calibration"] == str(yaml)
    assert any("rectified before matching" in n for n in report["notes"])
    # The same command again skips every pair; without --write-rectified the rectified
    # images of the earlier run are removed (the pair is redone).
    assert run_cli(
        "batch", inp, "-o", out, "--calib", yaml, "--translation-unit", "mm",
        "--num-disparities", NDISP, "--method", method, "--write-rectified", "--ply", "--quiet",
    ) == 0  # fmt: skip
    assert tb.report_of(out)["counts"]["skipped"] == 2
    assert run_cli(
        "batch", inp, "-o", out, "--calib", yaml, "--translation-unit", "mm",
        "--num-disparities", NDISP, "--method", method, "--quiet",
    ) == 0  # fmt: skip
    assert tb.report_of(out)["counts"]["ok"] == 2
    assert not list(out.glob("*-rectified.png"))


def test_batch_equals_match_on_the_same_raw_pair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One rule: batch writes what ``stereodepth match`` writes for each pair."""
    inp, calib = raw_folder(tmp_path, 1)
    ros_l = mr.ros_camera_info(
        tmp_path / "l.yaml", calib.K1, calib.D1, calib.R1, calib.P1, (96, 64)
    )
    ros_r = mr.ros_camera_info(
        tmp_path / "r.yaml", calib.K2, calib.D2, calib.R2, calib.P2, (96, 64)
    )
    out = tmp_path / "out"
    assert run_cli(
        "batch", inp, "-o", out, "--calib", ros_l, "--calib-right", ros_r,
        "--num-disparities", NDISP, "--format", "pfm", "--quiet",
    ) == 0  # fmt: skip
    m = tmp_path / "match"
    assert run_cli(
        "match", inp / "p0" / "left.png", inp / "p0" / "right.png", "--calib", ros_l,
        "--calib-right", ros_r, "--num-disparities", NDISP, "--depth-format", "pfm",
        "--no-preview", "-o", f"{m}/", "--json",
    ) == 0  # fmt: skip
    summary = json.loads(capsys.readouterr().out)
    assert summary["rectified"] is True
    # batch writes the disparity in Middlebury's convention (+inf holes, write_disparity_pfm);
    # compared as maps, so that either convention of match's file reads the same.
    assert (
        io.read_disparity_pfm(out / "p0.disparity.pfm").tobytes()
        == io.read_disparity_pfm(m / "disparity.pfm").tobytes()
    )
    assert (out / "p0.depth.pfm").read_bytes() == (m / "depth.pfm").read_bytes()
    record = json.loads((out / "p0.record.json").read_text())
    assert record["calibration_source"] == f"--calib {ros_l}, {ros_r} (rectified)"


def test_alpha_recomputes_the_rectification_in_batch_as_in_match(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--alpha`` replaces the file's own transforms by Bouguet's with that alpha, in both
    commands (one rule), and a rerun with another alpha redoes the pair."""
    from stereodepth.rectify import StereoRectifier

    inp, calib = raw_folder(tmp_path, 1)
    yaml = mr.write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=True)
    out = tmp_path / "out"
    common = ["--calib", yaml, "--translation-unit", "mm", "--num-disparities", NDISP]
    assert (
        run_cli("batch", inp, "-o", out, *common, "--alpha", "0", "--format", "pfm", "--quiet") == 0
    )
    m = tmp_path / "match"
    assert run_cli(
        "match", inp / "p0" / "left.png", inp / "p0" / "right.png", *common, "--alpha", "0",
        "--depth-format", "pfm", "--no-preview", "-o", f"{m}/", "--json",
    ) == 0  # fmt: skip
    capsys.readouterr()
    assert (out / "p0.depth.pfm").read_bytes() == (m / "depth.pfm").read_bytes()
    expected = StereoRectifier.from_file(yaml, translation_unit="mm", alpha=0.0).rig
    stored = StereoRectifier.from_file(yaml, translation_unit="mm").rig
    assert expected.focal_px != stored.focal_px  # alpha 0 zooms in: a real change
    record = json.loads((out / "p0.record.json").read_text())
    settings = record["settings"]
    assert settings["calibration"]["focal_px"] == pytest.approx(expected.focal_px, rel=1e-12)
    assert settings["rectification"]["alpha"] == 0.0
    first = (out / "p0.depth.pfm").read_bytes()
    assert (
        run_cli("batch", inp, "-o", out, *common, "--alpha", "1", "--format", "pfm", "--quiet") == 0
    )
    assert (out / "p0.depth.pfm").read_bytes() != first


@pytest.mark.parametrize("method", ["bm", "sgm"])
def test_vertical_rig_matched_transposed_as_match_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], method: str
) -> None:
    """The sample pair transposed is a rectified vertical pair (second camera below): batch
    gives the horizontal pair's disparity transposed, byte for byte as ``stereodepth match``."""
    pytest.importorskip("yaml", reason="YAML calibrations need PyYAML (the calib extra)")
    from PIL import Image

    s = sample_pair(96, 64)
    d = tmp_path / "in" / "p0"
    d.mkdir(parents=True)
    up, down = (np.ascontiguousarray(np.swapaxes(a, 0, 1)) for a in (s.left, s.right))
    Image.fromarray(up).save(d / "left.png")
    Image.fromarray(down).save(d / "right.png")
    h, w = up.shape[:2]
    K = np.array([[100.0, 0, (w - 1) / 2], [0, 100.0, (h - 1) / 2], [0, 0, 1]])
    c = types.SimpleNamespace(
        K1=K, D1=np.zeros(5), K2=K, D2=np.zeros(5), R=np.eye(3), T=np.array([0, -0.1, 0]),
        image_size=(w, h),
    )  # fmt: skip
    yaml = mr.write_opencv_yaml(tmp_path / "vertical.yml", c, stored=False)
    common = ["--calib", yaml, "--translation-unit", "mm", "--num-disparities", "32"]
    out = tmp_path / "out"
    assert run_cli(
        "batch", d.parent, "-o", out, *common, "--method", method, "--format", "pfm", "--quiet"
    ) == 0  # fmt: skip
    match = stereodepth.block_match if method == "bm" else stereodepth.semi_global_match
    horizontal = match(s.left, s.right, num_disparities=32)
    assert isinstance(horizontal, np.ndarray)
    disparity = io.read_disparity_pfm(out / "p0.disparity.pfm")  # +inf holes read as NaN
    assert disparity.tobytes() == np.ascontiguousarray(horizontal.T).tobytes()
    m = tmp_path / "match"
    assert run_cli(
        "match", d / "left.png", d / "right.png", *common, "--method", method,
        "--depth-format", "pfm", "--disparity-format", "pfm", "--no-preview", "-o", f"{m}/",
    ) == 0  # fmt: skip
    capsys.readouterr()
    assert (out / "p0.depth.pfm").read_bytes() == (m / "depth.pfm").read_bytes()


def test_a_pair_of_another_size_fails_alone(tmp_path: Path) -> None:
    inp, calib = raw_folder(tmp_path, 1)
    odd = inp / "odd"
    odd.mkdir()
    s = sample_pair(80, 64)
    from PIL import Image

    Image.fromarray(s.left).save(odd / "left.png")
    Image.fromarray(s.right).save(odd / "right.png")
    yaml = mr.write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=True)
    out = tmp_path / "out"
    assert run_cli(
        "batch", inp, "-o", out, "--calib", yaml, "--translation-unit", "mm",
        "--num-disparities", NDISP, "--quiet",
    ) == 1  # fmt: skip
    pairs = {p["stem"]: p for p in tb.report_of(out)["pairs"]}
    assert pairs["p0"]["status"] == "ok"
    assert pairs["odd"]["status"] == "failed"
    assert pairs["odd"]["error"] == (
        f"the pair is 80x64 px, and --calib {yaml} is the calibration of 96x64 px images"
    )
    assert pairs["odd"]["rectified"] is True


def test_the_rectifier_travels_as_its_calibration_and_is_built_once_per_process(
    tmp_path: Path,
) -> None:
    _inp, calib = raw_folder(tmp_path, 1)
    yaml = mr.write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=False)
    found = batch.calibration.raw_rectification(str(yaml), translation_unit="mm", threads=1)
    assert found is not None
    rectifier, rig = found
    options = batch.BatchOptions(out_dir=tmp_path / "out", rectification=rectifier)
    blob = pickle.dumps(options)
    assert len(blob) < 4096  # the calibration, not the maps
    back = pickle.loads(blob)
    assert back.rectification == rectifier
    # In this process the rectifier built to check the file is the one pairs use.
    assert back.rectification.rectifier(1) is rectifier.rectifier(1)
    assert rectifier.rectifier(2) is rectifier.rectifier(2)
    assert rig.focal_px == rectifier.rectifier(1).rig.focal_px


# (flags after INPUT -o OUT; {raw} the raw YAML, {mb} a Middlebury calib.txt), the message
BAD: list[tuple[list[str], str]] = [
    (
        ["--calib", "{raw}", "--translation-unit", "mm", "--num-disparities", "16", "--no-rectify"],
        "--calib: {raw} is the calibration of a raw (unrectified) pair and --no-rectify forbids "
        "rectifying it",
    ),
    (["--write-rectified", "--num-disparities", "16"], "--write-rectified goes with --calib FILE"),
    (["--no-rectify", "--num-disparities", "16"], "--no-rectify goes with --calib FILE"),
    (["--calib-right", "{raw}", "--num-disparities", "16"], "--calib-right goes with --calib"),
    (
        ["--calib", "{mb}", "--translation-unit", "mm"],
        "--translation-unit does not apply to {mb}, a Middlebury or KITTI calibration of a pair "
        "that is already rectified",
    ),
    (["--calib", "{mb}", "--write-rectified"], "--write-rectified does not apply to {mb}"),
    (
        ["--calib", "{raw}", "--translation-unit", "mm"],
        "--num-disparities is required: --calib {raw} has no ndisp",
    ),
    (
        [
            "--calib",
            "{raw}",
            "--translation-unit",
            "mm",
            "--num-disparities",
            "16",
            "--focal-px",
            "500",
            "--baseline-mm",
            "100",
        ],
        "give --focal-px and --baseline-mm, or --calib, not both",
    ),
    (
        ["--calib", "{raw}", "--translation-unit", "km", "--num-disparities", "16"],
        "argument --translation-unit: invalid choice: 'km'",
    ),
    (["--calib", "{raw}.absent", "--num-disparities", "16"], "--calib: calibration file not found"),
    (
        ["--calib", "{vertical}", "--translation-unit", "mm", "--num-disparities", "16"],
        "--calib: {vertical}: the first camera is below the second",
    ),
    (["--calib", "{garbage}", "--num-disparities", "16"], "--calib: "),
    (["--alpha", "0", "--num-disparities", "16"], "--alpha goes with --calib FILE"),
    (
        ["--distortion-model", "plumb_bob", "--num-disparities", "16"],
        "--distortion-model goes with --calib FILE",
    ),
    (["--calib", "{mb}", "--distortion-model", "plumb_bob"], "--distortion-model does not apply"),
    (["--calib", "{mb}", "--image-size", "40", "24"], "--image-size does not apply to {mb}"),
    (["--image-size", "40", "24", "--num-disparities", "16"], "--image-size goes with --calib"),
    (
        [
            *("--calib", "{raw}", "--translation-unit", "mm", "--num-disparities", "16"),
            *("--image-size", "41", "24"),
        ],
        "the file gives an image size of (",
    ),
    (
        ["--calib", "{fish}", "--translation-unit", "mm", "--num-disparities", "16"],
        "{fish}: D1 has 4 coefficients, which both OpenCV's fisheye module",
    ),
    (
        [
            "--calib",
            "{raw}",
            "--translation-unit",
            "mm",
            "--num-disparities",
            "16",
            "--distortion-model",
            "equidistant",
        ],
        "{raw}: D1 has 5 coefficients; the equidistant model takes 4",
    ),
    (["--calib", "{mb}", "--alpha", "0"], "--alpha does not apply to {mb}"),
    (
        ["--calib", "{raw}", "--translation-unit", "mm", "--num-disparities", "16", "--alpha", "2"],
        "--alpha must be -1 (OpenCV's default scaling) or in [0, 1], got 2.0",
    ),
    (
        [
            "--calib",
            "{raw}",
            "--translation-unit",
            "mm",
            "--num-disparities",
            "16",
            "--alpha",
            "nan",
        ],
        "--alpha must be -1 (OpenCV's default scaling) or in [0, 1], got nan",
    ),
]


@pytest.mark.parametrize(("flags", "fragment"), BAD, ids=[" ".join(b[0]) for b in BAD])
def test_bad_rectification_flags_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], fragment: str
) -> None:
    inp, calib = raw_folder(tmp_path, 1)
    raw = mr.write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=True)
    mb = tmp_path / "calib.txt"
    mb.write_text(tb.calib_text())
    vertical = calib.__class__(**{**calib.__dict__, "R": np.eye(3), "T": np.array([0, 0.1, 0])})
    vertical_yaml = mr.write_opencv_yaml(tmp_path / "vertical.yml", vertical, stored=False)
    (tmp_path / "garbage.yml").write_text("stereo: [1, 2\n")
    d = np.array([0.05, -0.01, 0.002, -0.0004])  # cv2.fisheye's k1..k4, or plumb_bob's?
    fish = calib.__class__(**{**calib.__dict__, "D1": d, "D2": d})
    fish_yaml = mr.write_opencv_yaml(tmp_path / "fish.yml", fish, stored=False)
    subst = {
        "{fish}": str(fish_yaml),
        "{raw}": str(raw),
        "{mb}": str(mb),
        "{vertical}": str(vertical_yaml),
        "{garbage}": str(tmp_path / "garbage.yml"),
    }

    def fill(text: str) -> str:
        for k, v in subst.items():
            text = text.replace(k, v)
        return text

    try:
        status = cli.main(["batch", str(inp), "-o", str(tmp_path / "out"), *map(fill, flags)])
    except SystemExit as exc:  # argparse's own errors
        status = int(exc.code or 0)
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.count("\n") == 1 and err.startswith("stereodepth batch: error: "), err
    assert fill(fragment) in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()


@pytest.mark.cluster
def test_raw_pairs_on_a_local_cluster(tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    inp, calib = raw_folder(tmp_path, 4)
    yaml = mr.write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=False)
    flags = [
        "--calib", str(yaml), "--translation-unit", "mm", "--num-disparities", str(NDISP),
        "--ply", "--write-rectified", "--quiet",
    ]  # fmt: skip
    assert run_cli("batch", inp, "-o", tmp_path / "here", *flags) == 0
    # dashboard_address: a free loopback port (None would still try 8787, and warn if taken)
    with (
        distributed.LocalCluster(
            n_workers=2,
            processes=True,
            threads_per_worker=1,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        there = tmp_path / "there"
        assert (
            run_cli("batch", inp, "-o", there, *flags, "--scheduler", cluster.scheduler_address)
            == 0
        )

        def built() -> int:
            from stereodepth.batch import calibration

            return len(calibration._RECTIFIERS)

        # Each worker process built the job's rectifier once (one entry), whatever the number
        # of pairs it rectified.
        per_worker = client.run(built)
    assert set(per_worker.values()) <= {0, 1} and sum(per_worker.values()) >= 1
    assert tb.outputs_bytes(there) == tb.outputs_bytes(tmp_path / "here")
    report = tb.report_of(there)
    assert report["counts"]["ok"] == 4
    assert all(p["rectified"] for p in report["pairs"])


def test_outputs_of_an_earlier_job_inside_input_are_not_pairs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``S.left-rectified.png`` and ``S.right-rectified.png`` of an earlier job whose OUTDIR
    lies in INPUT are outputs: they were taken for a new raw pair and rectified a second time
    by the next job, silently."""
    inp, calib = raw_folder(tmp_path)
    yaml = mr.write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=False)
    flags = ["--calib", yaml, "--translation-unit", "mm", "--num-disparities", NDISP]
    assert run_cli("batch", inp, "-o", inp / "first", *flags, "--write-rectified", "--quiet") == 0
    assert (inp / "first" / "p0.left-rectified.png").is_file()
    capsys.readouterr()
    assert run_cli("batch", inp, "-o", tmp_path / "second", *flags, "--method", "sgm") == 0
    report = json.loads((tmp_path / "second" / "report.json").read_text())
    assert sorted(p["stem"] for p in report["pairs"]) == ["p0", "p1"]
    err = capsys.readouterr().err
    assert f"skipped {inp / 'first'}: the outputs of an earlier batch job" in err
    # OUTDIR = INPUT: the second run finds the same pairs, all done.
    assert run_cli("batch", inp / "p0", "-o", inp / "p0", *flags, "--write-rectified") == 0
    assert run_cli("batch", inp / "p0", "-o", inp / "p0", *flags, "--write-rectified") == 0
    report = json.loads((inp / "p0" / "report.json").read_text())
    assert [(p["stem"], p["status"]) for p in report["pairs"]] == [("p0", "skipped")]


def test_no_output_is_an_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A CSV list whose images carry the names of a pair's outputs in OUTDIR: the job wrote
    the rectified pair over its own raw input (and could remove it as stale). Refused."""
    inp, calib = raw_folder(tmp_path, n=1)
    yaml = mr.write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=False)
    left = (inp / "p0" / "left.png").rename(inp / "p.left-rectified.png")
    right = (inp / "p0" / "right.png").rename(inp / "p.right-rectified.png")
    before = [left.read_bytes(), right.read_bytes()]
    (inp / "list.csv").write_text("p.left-rectified.png,p.right-rectified.png,p\n")
    for extra in (["--write-rectified"], []):
        code = run_cli(
            "batch", inp / "list.csv", "-o", inp, "--calib", yaml, "--translation-unit", "mm",
            "--num-disparities", NDISP, "--quiet", *extra,
        )  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1, err
        assert f"pair 'p' would write {inp / 'p.left-rectified.png'}, which is the input" in err
    assert [left.read_bytes(), right.read_bytes()] == before
    assert sorted(p.name for p in inp.iterdir()) == [
        "list.csv", "p.left-rectified.png", "p.right-rectified.png", "p0",
    ]  # fmt: skip


def test_a_job_killed_mid_pair_with_outdir_inside_input_resumes(tmp_path: Path) -> None:
    """OUTDIR = INPUT and --write-rectified, the job killed (SIGKILL) after the rectified pair
    was written and before the pair's record, which lists it: ``p0.left-rectified.png`` was
    then found as a new pair, which pair ``p0`` writes, so every later run was refused
    ('which is the input ...: choose another OUTDIR') and the job could not be resumed."""

    inp, calib = raw_folder(tmp_path, n=1)
    scene = inp / "p0"
    yaml = mr.write_opencv_yaml(tmp_path / "stereo.yml", calib, stored=False)
    argv = [
        "batch", str(scene), "-o", str(scene), "--calib", str(yaml), "--translation-unit", "mm",
        "--num-disparities", str(NDISP), "--write-rectified", "--quiet",
    ]  # fmt: skip
    tb.killed_at(argv, tb.hang_on_depth("p0"), "writing the depth")
    assert (scene / "p0.left-rectified.png").is_file()
    # the record written before the pair's first file, which lists them
    assert json.loads((scene / "p0.record.json").read_text())["status"] == "started"
    assert run_cli(*argv) == 0
    report = json.loads((scene / "report.json").read_text())
    assert [(p["stem"], p["status"]) for p in report["pairs"]] == [("p0", "ok")]
    # the rectified images are known as p0's outputs from its record, not taken for a pair
    assert not any("left-rectified" in n for n in report["notes"]), report["notes"]
    rect = StereoRectifier.from_calibration(read_stereo_calibration(yaml, translation_unit="mm"))
    disparity, depth, rect_l, rect_r = expected(scene / "left.png", scene / "right.png", rect)
    np.testing.assert_array_equal(np.load(scene / "p0.disparity.npy"), disparity, strict=True)
    np.testing.assert_array_equal(np.load(scene / "p0.depth.npy"), depth, strict=True)
    np.testing.assert_array_equal(io.read_image(scene / "p0.left-rectified.png"), rect_l)
    np.testing.assert_array_equal(io.read_image(scene / "p0.right-rectified.png"), rect_r)
    assert sorted(p.name for p in scene.iterdir()) == [
        "left.png", "p0.depth.npy", "p0.disparity.npy", "p0.left-rectified.png",
        "p0.record.json", "p0.right-rectified.png", "report.json", "right.png",
    ]  # fmt: skip
