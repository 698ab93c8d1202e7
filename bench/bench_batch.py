"""Batch depth jobs on the shared scenes, in pairs per second: ``stereodepth batch`` in this
process, on a 2-worker LocalCluster, and a plain Python loop over OpenCV's StereoBM with
``np.where`` for depth. Plus the reprojection kernel against OpenCV and its oracle.

    pytest bench/bench_batch.py

Every job reads the ten scenes' PNGs, matches them and writes the disparity and the depth as
.npy files into a fresh folder; each benchmark checks what was written. The scenes are laid
out as Middlebury folders (im0.png, im1.png, calib.txt with ndisp = the scene's max disparity
rounded up to a multiple of 16, which OpenCV needs) in a temporary folder of symbolic links.
Scenes without a published calibration get focal 1000 px, baseline 100 mm: depth values do not
change the work.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import batch, reference
from stereodepth import io as sdio
from stereodepth.pointcloud import q_matrix


def data_dir() -> Path:
    env = os.environ.get("STEREODEPTH_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "stereo"


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, Any]]:
    """The shared scenes as Middlebury folders: [{name, dir, ndisp, focal, baseline_mm,
    doffs}]."""
    root = data_dir()
    found = (
        sorted(p for p in root.iterdir() if (p / "meta.json").is_file()) if root.is_dir() else []
    )
    if not found:
        pytest.skip(f"shared stereo scenes not found at {root}")
    out = tmp_path_factory.mktemp("scenes")
    info = []
    for p in found:
        meta = json.loads((p / "meta.json").read_text())
        d = out / p.name
        d.mkdir()
        (d / "im0.png").symlink_to(p / "left.png")
        (d / "im1.png").symlink_to(p / "right.png")
        ndisp = 16 * math.ceil((meta["max_disp"] + 1) / 16)
        focal = meta.get("focal_px") or 1000.0
        baseline = meta.get("baseline_mm") or 100.0
        doffs = meta.get("doffs") or 0.0
        (d / "calib.txt").write_text(
            f"cam0=[{focal} 0 {meta['width'] / 2}; 0 {focal} {meta['height'] / 2}; 0 0 1]\n"
            f"doffs={doffs}\nbaseline={baseline}\nndisp={ndisp}\n"
        )
        info.append(
            {
                "name": p.name,
                "dir": d,
                "ndisp": ndisp,
                "focal": focal,
                "baseline_mm": baseline,
                "doffs": doffs,
            }
        )
    return info


@pytest.fixture(scope="module")
def pairs(scenes: list[dict[str, Any]]) -> list[batch.Pair]:
    return batch.resolve_calibration(batch.find_pairs(scenes[0]["dir"].parent))


@pytest.fixture
def fresh(tmp_path: Path) -> Any:
    """A new, empty output folder per round (so nothing is skipped as already done)."""
    count = [0]

    def make() -> tuple[tuple[Path], dict[str, Any]]:
        count[0] += 1
        d = tmp_path / f"round{count[0]}"
        if d.exists():
            shutil.rmtree(d)
        d.mkdir()
        return (d,), {}

    return make


@pytest.fixture(scope="module")
def cluster_address() -> Iterator[str]:
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2,
        processes=True,
        threads_per_worker=1,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
    ) as cluster:
        yield cluster.scheduler_address


GROUP = "batch: 10 shared scenes, disparity + depth to .npy"
ROUNDS = 7


def check_outputs(out: Path, scenes: list[dict[str, Any]]) -> None:
    for s in scenes:
        d = np.load(out / f"{s['name']}.disparity.npy")
        z = np.load(out / f"{s['name']}.depth.npy")
        assert d.dtype == z.dtype == np.float32 and d.shape == z.shape
        assert np.isfinite(d).mean() > 0.2, s["name"]


def run_ours(out: Path, pairs: list[batch.Pair], **kw: Any) -> batch.BatchReport:
    report = batch.run_batch(pairs, batch.BatchOptions(out_dir=out), **kw)
    assert report.counts["ok"] == len(pairs), report.failed
    return report


def test_batch_embedded(
    benchmark: Any, impl: Any, fresh: Any, pairs: list[batch.Pair], scenes: list[dict[str, Any]]
) -> None:
    benchmark.group = GROUP
    impl("stereodepth")  # batch embedded: EMBEDDED_IN_FLIGHT pairs at a time
    outs: list[Path] = []
    benchmark.pedantic(
        lambda out: outs.append(out) or run_ours(out, pairs),
        setup=fresh,
        rounds=ROUNDS,
        iterations=1,
        warmup_rounds=1,
    )
    check_outputs(outs[-1], scenes)
    benchmark.extra_info["pairs"] = len(pairs)


@pytest.mark.parametrize("in_flight", [1, 2])
def test_batch_embedded_fewer_in_flight(
    benchmark: Any,
    impl: Any,
    fresh: Any,
    pairs: list[batch.Pair],
    scenes: list[dict[str, Any]],
    monkeypatch: pytest.MonkeyPatch,
    in_flight: int,
) -> None:
    """The embedded runner with fewer pairs at a time than its default: what overlapping
    reading and writing with matching buys."""
    benchmark.group = GROUP
    impl(f"stereodepth, {in_flight} pair{'s' if in_flight > 1 else ''} in flight")
    monkeypatch.setattr(batch, "EMBEDDED_IN_FLIGHT", in_flight)
    outs: list[Path] = []
    benchmark.pedantic(
        lambda out: outs.append(out) or run_ours(out, pairs),
        setup=fresh,
        rounds=ROUNDS,
        iterations=1,
        warmup_rounds=1,
    )
    check_outputs(outs[-1], scenes)


def test_batch_local_cluster(
    benchmark: Any,
    impl: Any,
    fresh: Any,
    pairs: list[batch.Pair],
    scenes: list[dict[str, Any]],
    cluster_address: str,
) -> None:
    """The same job on an already running LocalCluster of 2 worker processes, 1 thread each
    (the matcher then uses every core in each worker, as --scheduler does by default)."""
    benchmark.group = GROUP
    impl("stereodepth, LocalCluster 2 workers")
    outs: list[Path] = []
    benchmark.pedantic(
        lambda out: outs.append(out) or run_ours(out, pairs, scheduler=cluster_address),
        setup=fresh,
        rounds=ROUNDS,
        iterations=1,
        warmup_rounds=1,
    )
    check_outputs(outs[-1], scenes)


def python_loop_stereodepth(out: Path, scenes: list[dict[str, Any]]) -> None:
    """What the batch command does, written as a plain loop (no resume, no records)."""
    for s in scenes:
        left = sdio.read_image(s["dir"] / "im0.png")
        right = sdio.read_image(s["dir"] / "im1.png")
        d = stereodepth.block_match(left, right, num_disparities=s["ndisp"])
        z = stereodepth.disparity_to_depth(
            d, focal_px=s["focal"], baseline_m=s["baseline_mm"] / 1000, doffs_px=s["doffs"]
        )
        np.save(out / f"{s['name']}.disparity.npy", d)
        np.save(out / f"{s['name']}.depth.npy", z)


def test_python_loop_stereodepth(
    benchmark: Any, impl: Any, fresh: Any, scenes: list[dict[str, Any]]
) -> None:
    benchmark.group = GROUP
    impl("python loop: block_match")
    outs: list[Path] = []
    benchmark.pedantic(
        lambda out: outs.append(out) or python_loop_stereodepth(out, scenes),
        setup=fresh,
        rounds=ROUNDS,
        iterations=1,
        warmup_rounds=1,
    )
    check_outputs(outs[-1], scenes)


def python_loop_opencv(cv2: Any, out: Path, scenes: list[dict[str, Any]]) -> None:
    """The usual script: StereoBM on grey images, /16, np.where for depth."""
    for s in scenes:
        left = cv2.imread(str(s["dir"] / "im0.png"), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(s["dir"] / "im1.png"), cv2.IMREAD_GRAYSCALE)
        bm = cv2.StereoBM_create(numDisparities=s["ndisp"], blockSize=9)
        d = bm.compute(left, right).astype(np.float32) / 16.0
        d = np.where(d > 0, d, np.float32(np.nan))
        k = s["focal"] * s["baseline_mm"] / 1000
        with np.errstate(invalid="ignore"):
            z = np.where(d > 0, k / (d + s["doffs"]), np.nan).astype(np.float32)
        np.save(out / f"{s['name']}.disparity.npy", d)
        np.save(out / f"{s['name']}.depth.npy", z)


def test_python_loop_opencv_stereobm(
    benchmark: Any, impl: Any, fresh: Any, scenes: list[dict[str, Any]]
) -> None:
    cv2 = pytest.importorskip("cv2")
    benchmark.group = GROUP
    impl("python loop: OpenCV StereoBM + np.where")
    outs: list[Path] = []
    benchmark.pedantic(
        lambda out: outs.append(out) or python_loop_opencv(cv2, out, scenes),
        setup=fresh,
        rounds=ROUNDS,
        iterations=1,
        warmup_rounds=1,
    )
    check_outputs(outs[-1], scenes)


# --- point clouds -----------------------------------------------------------------------------
REPROJECT_SHAPE = (1080, 1920)
RIG = {"focal_px": 1400.0, "baseline_m": 0.12, "cx_px": 960.0, "cy_px": 540.0, "doffs_px": 0.0}


@pytest.fixture(scope="module")
def reproject_case() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    d = rng.random(REPROJECT_SHAPE, dtype=np.float32) * 190 + 1
    d[rng.random(REPROJECT_SHAPE) < 0.05] = np.nan
    return d, reference.reproject(d, **RIG)


RGROUP = f"reproject {REPROJECT_SHAPE} float32 -> XYZ float32"


def test_reproject_stereodepth(benchmark: Any, impl: Any, reproject_case: Any) -> None:
    d, want = reproject_case
    benchmark.group = RGROUP
    impl("stereodepth")
    out = np.empty((*d.shape, 3), np.float32)
    benchmark(stereodepth.reproject, d, **RIG, out=out)
    np.testing.assert_array_equal(out, want)


def test_reproject_stereodepth_one_thread(benchmark: Any, impl: Any, reproject_case: Any) -> None:
    d, want = reproject_case
    benchmark.group = RGROUP
    impl("stereodepth threads=1")
    out = np.empty((*d.shape, 3), np.float32)
    benchmark(stereodepth.reproject, d, **RIG, out=out, threads=1)
    np.testing.assert_array_equal(out, want)


def test_reproject_opencv(benchmark: Any, impl: Any, reproject_case: Any) -> None:
    cv2 = pytest.importorskip("cv2")
    d, want = reproject_case
    benchmark.group = RGROUP
    impl("OpenCV reprojectImageTo3D")
    q = q_matrix(**RIG)
    got = benchmark(cv2.reprojectImageTo3D, d, q)
    ok = np.isfinite(want).all(axis=-1)
    np.testing.assert_allclose(got[ok], want[ok], rtol=3e-7, atol=1e-6)


def test_reproject_oracle(benchmark: Any, impl: Any, reproject_case: Any) -> None:
    d, want = reproject_case
    benchmark.group = RGROUP
    impl("oracle (stereodepth.reference)")
    got = benchmark.pedantic(reference.reproject, args=(d,), kwargs=RIG, rounds=3, iterations=1)
    np.testing.assert_array_equal(got, want)
