"""``stereodepth batch --method bm|sgm``: the semi-global matcher in batch jobs gives, pair by
pair and bit for bit, what :func:`stereodepth.semi_global_match` gives on the same pair (here
and on a real Dask LocalCluster); the method and its options are in every record and in the
report; options are checked per method before the first pair (one line, exit status 2)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import cli, io
from stereodepth.sample import sample_pair

Image = pytest.importorskip("PIL.Image")


def _test_batch() -> ModuleType:
    """tests/test_batch.py as a module, for its input builders (pytest imports test files with
    importlib, so they cannot import each other by name)."""
    path = Path(__file__).with_name("test_batch.py")
    spec = importlib.util.spec_from_file_location("_batch_builders", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


tb = _test_batch()


def run_cli(*argv: str | Path) -> int:
    return cli.main([str(a) for a in argv])


def sgm_expected(scene: Path, **params: Any) -> tuple[np.ndarray, np.ndarray]:
    """semi_global_match and disparity_to_depth of a scene, called directly."""
    left, right = io.read_image(scene / "im0.png"), io.read_image(scene / "im1.png")
    disparity = stereodepth.semi_global_match(
        left, right, num_disparities=tb.CALIB["ndisp"], **params
    )
    assert isinstance(disparity, np.ndarray)
    depth = stereodepth.disparity_to_depth(
        disparity,
        focal_px=tb.CALIB["focal"],
        baseline_m=tb.CALIB["baseline_mm"] / 1000,
        doffs_px=tb.CALIB["cx1"] - tb.CALIB["cx"],
    )
    return disparity, depth


@pytest.mark.parametrize(
    ("flags", "params"),
    [
        ([], {}),
        (
            ["--option", "paths=8", "--option", "p2=300", "--block-size", "1", "--option",
             "fill=true", "--min-disparity", "1"],
            {"paths": 8, "p2": 300, "block_size": 1, "fill": True, "min_disparity": 1},
        ),
        # p1 above the default p2 (500) is valid with its own p2: it was refused.
        (["--option", "p1=600", "--option", "p2=700"], {"p1": 600, "p2": 700}),
    ],
    ids=["defaults", "options", "p1-above-the-default-p2"],
)  # fmt: skip
def test_sgm_outputs_equal_semi_global_match(
    tmp_path: Path, flags: list[str], params: dict[str, Any]
) -> None:
    names = tb.middlebury_folder(tmp_path / "in", 3)
    out = tmp_path / "out"
    assert run_cli("batch", tmp_path / "in", "-o", out, "--method", "sgm", "--quiet", *flags) == 0
    for name in names:
        disparity, depth = sgm_expected(tmp_path / "in" / name, **params)
        np.testing.assert_array_equal(
            np.load(out / f"{name}.disparity.npy"), disparity, strict=True
        )
        np.testing.assert_array_equal(np.load(out / f"{name}.depth.npy"), depth, strict=True)
        assert np.isfinite(disparity).mean() > 0.5
        record = json.loads((out / f"{name}.record.json").read_text())
        assert record["status"] == "ok"
        assert record["method"] == "sgm" and record["settings"]["method"] == "sgm"
        assert record["matcher_options"] == params == record["settings"]["matcher"]
        assert record["rectified"] is False
    report = tb.report_of(out)
    assert report["method"] == "sgm" and report["matcher_options"] == params
    assert [p["method"] for p in report["pairs"]] == ["sgm"] * 3
    # The block matcher's output differs: the method is really used.
    bm = stereodepth.block_match(
        io.read_image(tmp_path / "in" / names[0] / "im0.png"),
        io.read_image(tmp_path / "in" / names[0] / "im1.png"),
        num_disparities=16,
    )
    assert np.load(out / f"{names[0]}.disparity.npy").tobytes() != bm.tobytes()


def test_bm_stays_the_default_and_is_recorded(tmp_path: Path) -> None:
    names = tb.middlebury_folder(tmp_path / "in", 1)
    out = tmp_path / "out"
    assert run_cli("batch", tmp_path / "in", "-o", out, "--quiet", "--option", "lr_max_diff=2") == 0
    record = json.loads((out / f"{names[0]}.record.json").read_text())
    assert record["method"] == "bm" and record["matcher_options"] == {"lr_max_diff": 2}
    left = io.read_image(tmp_path / "in" / names[0] / "im0.png")
    right = io.read_image(tmp_path / "in" / names[0] / "im1.png")
    want = stereodepth.block_match(left, right, num_disparities=16, lr_max_diff=2)
    np.testing.assert_array_equal(np.load(out / f"{names[0]}.disparity.npy"), want, strict=True)
    assert tb.report_of(out)["method"] == "bm"


def test_changing_the_method_redoes_the_pairs(tmp_path: Path) -> None:
    names = tb.middlebury_folder(tmp_path / "in", 2)
    out = tmp_path / "out"
    assert run_cli("batch", tmp_path / "in", "-o", out, "--quiet") == 0
    assert run_cli("batch", tmp_path / "in", "-o", out, "--quiet") == 0
    assert tb.report_of(out)["counts"]["skipped"] == 2
    assert run_cli("batch", tmp_path / "in", "-o", out, "--quiet", "--method", "sgm") == 0
    assert tb.report_of(out)["counts"] == {"ok": 2, "skipped": 0, "failed": 0, "cancelled": 0}
    for name in names:
        disparity, _ = sgm_expected(tmp_path / "in" / name)
        np.testing.assert_array_equal(np.load(out / f"{name}.disparity.npy"), disparity)
    assert run_cli("batch", tmp_path / "in", "-o", out, "--quiet", "--method", "sgm") == 0
    report = tb.report_of(out)
    assert report["counts"]["skipped"] == 2
    assert [p["method"] for p in report["pairs"]] == ["sgm", "sgm"]


# (flags), a fragment of the one-line message
BAD: list[tuple[list[str], str]] = [
    (
        ["--option", "p1=3"],
        "--option p1: an option of --method sgm; --method bm (block matching) has no option "
        "'p1' (its options: subpixel, uniqueness_ratio, texture_threshold,",
    ),
    (
        ["--method", "sgm", "--option", "texture_threshold=3"],
        "--option texture_threshold: an option of --method bm; --method sgm (semi-global "
        "matching) has no option 'texture_threshold' (its options: p1, p2, p2_step, paths,",
    ),
    (
        ["--method", "sgm", "--cost", "sad"],
        "--cost: an option of --method bm; --method sgm (semi-global matching) has no option "
        "'cost'",
    ),
    (
        ["--method", "sgm", "--option", "foo=1"],
        "--option foo: --method sgm (semi-global matching) has no option 'foo' (its options: p1,",
    ),
    (
        ["--method", "sgm", "--block-size", "5"],
        "--block-size 5: block_size must be 1 or 3 (box costs are stored in 8 bits), got 5",
    ),
    (
        ["--method", "sgm", "--option", "paths=8", "--option", "p2=9000"],
        "--option p2: p2 must be an integer in [p1, 8047] = [40, 8047] for paths=8",
    ),
    (
        ["--method", "sgm", "--option", "p1=600"],
        "--option p1: p2 must be an integer in [p1, 16239] = [600, 16239]",
    ),
    (  # p2 at fault, with the value given (p1 checked alone blamed p1, "got 250")
        ["--method", "sgm", "--option", "p1=500", "--option", "p2=10"],
        "--option p2: p2 must be an integer in [p1, 16239] = [500, 16239]",
    ),
    (["--method", "sgm", "--option", "paths=5"], "--option paths: paths must be 3, 4 or 8, got 5"),
    (["--method", "sgm", "--option", "fill=1"], "--option fill: fill must be a bool, got int 1"),
    (["--method", "sgm", "--option", "isa=avx2"], "--option isa: not available in batch"),
    (
        ["--method", "sgm", "--option", "cost=sad"],
        "--option cost: an option of --method bm; --method sgm (semi-global matching) has no "
        "option 'cost'",
    ),
    (["--method", "sgm", "--option", "block_size=1"], "--option block_size: use --block-size"),
    (["--method", "sgm", "--option", "threads=2"], "--option threads: use --threads"),
    (
        ["--method", "sgm", "--option", "max_memory_mb=0"],
        "--option max_memory_mb: max_memory_mb must be",
    ),
    (
        ["--method", "sgm", "--num-disparities", "5000"],
        "--num-disparities 5000: num_disparities must be an integer in [1, ",
    ),
    (["--method", "bm", "--block-size", "1"], "--block-size 1: block_size must be an odd"),
    (["--method", "mst"], "argument --method: invalid choice: 'mst' (choose from 'bm', 'sgm')"),
]


@pytest.mark.parametrize(("flags", "fragment"), BAD, ids=[" ".join(b[0]) for b in BAD])
def test_bad_options_are_refused_before_the_first_pair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], fragment: str
) -> None:
    tb.middlebury_folder(tmp_path / "in", 1)
    try:
        status = cli.main(["batch", str(tmp_path / "in"), "-o", str(tmp_path / "out"), *flags])
    except SystemExit as exc:  # argparse's own errors
        status = int(exc.code or 0)
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.count("\n") == 1 and err.startswith("stereodepth batch: error: "), err
    assert fragment in err, err
    for internal in ("Traceback", "SemiGlobalOptions", "BlockMatchOptions", "usage:"):
        assert internal not in err, err
    assert not (tmp_path / "out").exists()


def test_run_batch_with_the_method_in_batch_options(tmp_path: Path) -> None:
    """The library entry point: BatchOptions(method=..., matcher=...)."""
    from stereodepth import batch

    tb.middlebury_folder(tmp_path / "in", 2)
    pairs = batch.resolve_calibration(batch.find_pairs(tmp_path / "in"))
    options = batch.BatchOptions(out_dir=tmp_path / "out", method="sgm", matcher={"paths": 4})
    report = batch.run_batch(pairs, options)
    assert report.counts["ok"] == 2
    data = report.as_dict()
    assert data["method"] == "sgm" and data["matcher_options"] == {"paths": 4}
    for p in pairs:
        disparity, _ = sgm_expected(p.left.parent, paths=4)
        np.testing.assert_array_equal(
            np.load(tmp_path / "out" / f"{p.stem}.disparity.npy"), disparity
        )


@pytest.mark.cluster
def test_sgm_on_a_local_cluster_equals_embedded_and_direct(tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    names = tb.middlebury_folder(tmp_path / "in", 4)
    flags = ["--method", "sgm", "--option", "paths=4", "--ply", "--quiet"]
    assert run_cli("batch", tmp_path / "in", "-o", tmp_path / "here", *flags) == 0
    # dashboard_address: a free loopback port (None would still try 8787, and warn if taken)
    with distributed.LocalCluster(
        n_workers=2,
        processes=True,
        threads_per_worker=1,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
    ) as cluster:
        there = tmp_path / "there"
        assert (
            run_cli("batch", tmp_path / "in", "-o", there, *flags, "--scheduler",
                    cluster.scheduler_address)
            == 0
        )  # fmt: skip
    report = tb.report_of(there)
    assert report["runner"] == f"dask {cluster.scheduler_address}"
    assert report["method"] == "sgm" and report["counts"]["ok"] == 4
    assert tb.outputs_bytes(there) == tb.outputs_bytes(tmp_path / "here")
    for name in names:
        disparity, depth = sgm_expected(tmp_path / "in" / name, paths=4)
        np.testing.assert_array_equal(np.load(there / f"{name}.disparity.npy"), disparity)
        np.testing.assert_array_equal(np.load(there / f"{name}.depth.npy"), depth)


def test_tuple_option_reaches_the_matcher(tmp_path: Path) -> None:
    """``--option intensity_range=0,4095`` is the tuple (0, 4095): the option batch lists for
    both methods could not be given before (the value stayed the string '0,4095')."""
    assert cli.key_value_option("intensity_range=0,4095") == ("intensity_range", (0, 4095))
    assert cli.key_value_option("x=1, 2.5,none") == ("x", (1, 2.5, None))
    pair = sample_pair(96, 64, seed=3)
    scene = tmp_path / "in" / "s0"
    scene.mkdir(parents=True)
    images = [
        np.ascontiguousarray(im[..., 1]).astype(np.uint16) * 16 for im in (pair.left, pair.right)
    ]
    for name, image in zip(("left", "right"), images, strict=True):
        io.write_png16(scene / f"{name}.png", image)
    out = tmp_path / "out"
    for method, match in (("bm", stereodepth.block_match), ("sgm", stereodepth.semi_global_match)):
        assert run_cli(
            "batch", tmp_path / "in", "-o", out, "--focal-px", "100", "--baseline-mm", "100",
            "--num-disparities", "16", "--method", method, "--option", "intensity_range=0,4095",
            "--quiet",
        ) == 0  # fmt: skip
        want = match(*images, num_disparities=16, intensity_range=(0, 4095))
        np.testing.assert_array_equal(np.load(out / "s0.disparity.npy"), want, strict=True)
        record = json.loads((out / "s0.record.json").read_text())
        assert record["matcher_options"] == {"intensity_range": [0, 4095]}


def _pgm16(path: Path, image: np.ndarray, maxval: int = 4095) -> None:
    """A binary 16-bit PGM with a comment in its header (samples big-endian)."""
    head = f"P5\n# made by a test\n{image.shape[1]} {image.shape[0]}\n{maxval}\n".encode()
    path.write_bytes(head + image.astype(">u2").tobytes())


def _scenes(root: Path, bits: dict[str, str]) -> Path:
    """``root/in/<name>/left.*, right.*`` for each name: "8" an 8-bit PNG pair, "16" a 16-bit
    PNG pair, "16pgm" a 16-bit PGM pair."""
    pair = sample_pair(96, 64, seed=3)
    grey = [np.ascontiguousarray(im[..., 1]) for im in (pair.left, pair.right)]
    for name, kind in bits.items():
        scene = root / "in" / name
        scene.mkdir(parents=True)
        for side, image in zip(("left", "right"), grey, strict=True):
            if kind == "8":
                Image.fromarray(image).save(scene / f"{side}.png")
            elif kind == "16":
                io.write_png16(scene / f"{side}.png", image.astype(np.uint16) * 16)
            else:
                _pgm16(scene / f"{side}.pgm", image.astype(np.uint16) * 16)
    return root / "in"


RIG = ("--focal-px", "100", "--baseline-mm", "100", "--num-disparities", "16")


@pytest.mark.parametrize("method", ["bm", "sgm"])
def test_intensity_range_on_8_bit_pairs_is_refused_before_the_first_pair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], method: str
) -> None:
    """``--option intensity_range=0,4095`` (README's example of an option checked before the
    first pair) applies to 16-bit images only: on 8-bit pairs every pair failed and the job
    exited 1. It is now refused up front, from the images' headers: one line, exit status 2,
    nothing written."""
    inp = _scenes(tmp_path, {"a": "8", "b": "8"})
    out = tmp_path / "out"
    option = ("--method", method, "--option", "intensity_range=0,4095")
    assert run_cli("batch", inp, "-o", out, *RIG, *option) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured.err
    assert captured.err == (
        "stereodepth batch: error: --option intensity_range=0,4095 applies to 16-bit images "
        "only (8-bit ones are matched as they are), and all 2 pairs are 8-bit (the first: a, "
        f"{inp / 'a' / 'left.png'}): drop it\n"
    )
    assert not out.exists()
    # One pair: said so.
    assert run_cli("batch", inp / "a", "-o", out, *RIG, *option) == 2
    assert "and the pair is 8-bit (a: " in capsys.readouterr().err
    assert not out.exists()


def test_intensity_range_in_a_folder_mixing_8_and_16_bit_pairs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A folder mixing 8- and 16-bit pairs is refused as a whole, naming how many pairs are
    8-bit and the first (their left images' headers: a PNG's mode, a PGM's maxval); without
    the 8-bit pair it runs, the 16-bit PGM pair included."""
    inp = _scenes(tmp_path, {"a": "16", "b": "8", "c": "16pgm"})
    out = tmp_path / "out"
    option = ("--option", "intensity_range=0,4095", "--quiet")
    assert run_cli("batch", inp, "-o", out, *RIG, *option) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert (
        f"and 1 of the 3 pairs is 8-bit (b: {inp / 'b' / 'left.png'}): drop it, or run it "
        "on the 16-bit pairs alone\n"
    ) in err
    assert not out.exists()
    for f in (inp / "b").iterdir():
        f.unlink()
    (inp / "b").rmdir()
    assert run_cli("batch", inp, "-o", out, *RIG, *option) == 0
    for name in ("a", "c"):
        record = json.loads((out / f"{name}.record.json").read_text())
        assert record["status"] == "ok" and record["matcher_options"] == {
            "intensity_range": [0, 4095]
        }


def test_sample_bits_reads_the_header(tmp_path: Path) -> None:
    """The bit depth read_image gives, from the header only; None where the header does not
    say (the pair's own read then fails with its message)."""
    from stereodepth.batch.command import sample_bits

    grey = np.arange(64 * 96, dtype=np.uint16).reshape(64, 96) % 4096
    Image.fromarray((grey % 256).astype(np.uint8)).save(tmp_path / "8.png")
    Image.fromarray(np.dstack([(grey % 256).astype(np.uint8)] * 3)).save(tmp_path / "rgb.png")
    io.write_png16(tmp_path / "16.png", grey)
    _pgm16(tmp_path / "16.pgm", grey)
    (tmp_path / "8.pgm").write_bytes(b"P5 96 64 255\n" + (grey % 256).astype(np.uint8).tobytes())
    (tmp_path / "p1.pbm").write_bytes(b"P1\n2 1\n0 1\n")
    Image.fromarray(grey.astype(np.float32)).save(tmp_path / "f.tif")
    (tmp_path / "garbage.png").write_bytes(b"not an image")
    cases = {
        "8.png": 8, "rgb.png": 8, "16.png": 16, "16.pgm": 16, "8.pgm": 8, "p1.pbm": 8,
        "f.tif": None, "garbage.png": None, "missing.png": None,
    }  # fmt: skip
    for name, bits in cases.items():
        assert sample_bits(tmp_path / name) == bits, name
        if bits is not None:  # what read_image gives
            assert io.read_image(tmp_path / name).dtype == (np.uint8 if bits == 8 else np.uint16)
