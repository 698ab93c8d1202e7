"""``stereodepth eval``: scene discovery, disparity range, methods, scores, timing and output.

The scores the command prints are checked against an independent run of the same matcher
followed by :func:`stereodepth.metrics.evaluate`; synthetic random-dot scenes (written as real
PNG files) check that the pair is fed the right way round.
"""

from __future__ import annotations

import inspect
import json
import math
import re
import statistics
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import cli, matching
from stereodepth.evaluation import find_scenes, num_disparities_for
from stereodepth.metrics import evaluate

PIL_Image = pytest.importorskip("PIL.Image")


# --------------------------------------------------------------------------------------------
# Helpers


def random_dot_pair(
    height: int, width: int, bands: list[int], *, rgb: bool, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random-dot stereogram: horizontal bands of rows, each a plane at one disparity.

    left(x) = right(x - d); the ground truth is NaN in the left d columns (no match inside
    the right image)."""
    rng = np.random.default_rng(seed)
    dmax = max(bands)
    shape = (height, width + dmax, 3) if rgb else (height, width + dmax)
    texture = rng.integers(0, 256, shape, dtype=np.uint8)
    left = np.ascontiguousarray(texture[:, :width])
    right = np.empty_like(left)
    gt = np.full((height, width), np.nan, dtype=np.float32)
    edges = np.linspace(0, height, len(bands) + 1).astype(int)
    for d, y0, y1 in zip(bands, edges[:-1], edges[1:], strict=True):
        right[y0:y1] = texture[y0:y1, d : d + width]
        gt[y0:y1, d:] = d
    return left, right, gt


def write_png(path: Path, image: np.ndarray) -> None:
    PIL_Image.fromarray(image).save(path)


def write_scene(
    folder: Path,
    left: np.ndarray,
    right: np.ndarray,
    gt: np.ndarray,
    mask: np.ndarray | None = None,
    meta: dict[str, Any] | None = None,
) -> Path:
    folder.mkdir(parents=True)
    write_png(folder / "left.png", left)
    write_png(folder / "right.png", right)
    np.save(folder / "disp_gt.npy", gt)
    if mask is not None:
        np.save(folder / "mask_nonocc.npy", mask)
    if meta is not None:
        (folder / "meta.json").write_text(json.dumps(meta))
    return folder


def write_pfm(path: Path, image: np.ndarray) -> None:
    """Little-endian single-channel PFM, bottom row first (written here, not by the package)."""
    h, w = image.shape
    with open(path, "wb") as f:
        f.write(f"Pf\n{w} {h}\n-1.0\n".encode())
        f.write(image[::-1].astype("<f4").tobytes())


@pytest.fixture
def scenes_dir(tmp_path: Path) -> Path:
    """Two scenes: RGB with a mask and meta.json; grey with neither."""
    root = tmp_path / "scenes"
    left, right, gt = random_dot_pair(64, 128, [5, 11], rgb=True, seed=1)
    mask = np.ones(gt.shape, dtype=bool)
    mask[:, -10:] = False
    write_scene(root / "rds-a", left, right, gt, mask, {"max_disp": 11, "scene": "a"})
    left, right, gt = random_dot_pair(64, 150, [20], rgb=False, seed=2)
    write_scene(root / "rds-b", left, right, gt)
    (root / "not-a-scene").mkdir()
    (root / "README.md").write_text("not a scene")
    return root


def load(folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    with PIL_Image.open(folder / "left.png") as im:
        left = np.asarray(im)
    with PIL_Image.open(folder / "right.png") as im:
        right = np.asarray(im)
    mask_path = folder / "mask_nonocc.npy"
    mask = np.load(mask_path) if mask_path.exists() else None
    return left, right, np.load(folder / "disp_gt.npy"), mask


def run_eval(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = cli.main(["eval", *argv])
    out, err = capsys.readouterr()
    return status, out, err


def run_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    status, out, err = run_eval(capsys, *argv, "--json")
    assert status == 0, err
    report: dict[str, Any] = json.loads(out)
    return report


def rows_of(report: dict[str, Any], scene: str, method: str) -> list[dict[str, Any]]:
    return [r for r in report["results"] if r["scene"] == scene and r["method"] == method]


def assert_same_metrics(got: dict[str, Any], want: dict[str, Any]) -> None:
    assert set(got) == set(want)
    for key, value in want.items():
        if isinstance(value, float) and math.isnan(value):
            assert got[key] is None, key
        else:
            assert got[key] == pytest.approx(value, rel=1e-12, abs=0), key


def opencv_disparity(
    cv2: Any,
    kind: str,
    left: np.ndarray,
    right: np.ndarray,
    num_disparities: int,
    block_size: int,
    **setters: Any,
) -> np.ndarray:
    """OpenCV's matcher as the eval documentation describes it, written out independently."""
    if kind == "bm":
        m = cv2.StereoBM_create(numDisparities=num_disparities, blockSize=block_size)
    else:
        m = cv2.StereoSGBM_create(
            minDisparity=0,
            numDisparities=num_disparities,
            blockSize=block_size,
            P1=8 * block_size**2,
            P2=32 * block_size**2,
        )
    for name, value in setters.items():
        getattr(m, name)(value)
    if left.ndim == 3:
        left = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
        right = cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)
    raw = m.compute(left, right)
    d = raw.astype(np.float64) / 16.0
    d[raw < 0] = np.nan
    return d.astype(np.float32)


# --------------------------------------------------------------------------------------------
# Scenes and the disparity range


def test_find_scenes(scenes_dir: Path) -> None:
    found = find_scenes(scenes_dir)
    assert [s.name for s in found] == ["rds-a", "rds-b"]
    a, b = found
    assert a.mask_path == scenes_dir / "rds-a" / "mask_nonocc.npy"
    assert a.max_disparity_px == 11
    assert b.mask_path is None
    assert b.max_disparity_px is None
    assert [s.name for s in find_scenes(scenes_dir, ["*-b"])] == ["rds-b"]
    assert [s.name for s in find_scenes(scenes_dir / "rds-a")] == ["rds-a"]  # DIR is a scene


def test_num_disparities_for_against_definition() -> None:
    for tenth in range(0, 3000, 7):
        d = tenth / 10
        n = num_disparities_for(d)
        # the smallest multiple of 16 whose range 0 .. n-1 holds every integer up to ceil(d)
        smallest = next(k for k in range(16, 1000, 16) if k - 1 >= math.ceil(d))
        assert n == smallest, d
    assert [num_disparities_for(v) for v in (0, 14, 15, 16, 55, 64, 148)] == [
        16,
        16,
        16,
        32,
        64,
        80,
        160,
    ]


@pytest.mark.parametrize("fault", ["empty mask", "range", "mixed bit depths"])
def test_a_faulty_last_scene_is_reported_before_any_matching(
    scenes_dir: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    fault: str,
) -> None:
    """A scene that cannot be scored (a mask selecting nothing, a declared range its ground
    truth leaves, an 8-bit left image beside a 16-bit right one) was found only when its turn
    came: every scene before it had been matched and timed, and their results were lost with
    the error. Every scene is checked first; nothing is matched. (16-bit images for an OpenCV
    method are no fault: tests/test_eval_robustness.py.)"""
    import stereodepth.evaluation as evaluation

    calls: list[str] = []
    real = evaluation._timed

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls.append("matched")
        return real(*args, **kwargs)

    monkeypatch.setattr(evaluation, "_timed", counted)
    last = scenes_dir / "rds-b"  # after rds-a in name order
    methods = ["stereodepth"]
    if fault == "empty mask":
        np.save(last / "mask_nonocc.npy", np.zeros((64, 150), dtype=bool))
        want = "scene rds-b: " + str(last / "mask_nonocc.npy") + ": the mask selects none"
    elif fault == "range":
        (last / "meta.json").write_text('{"max_disp": 3}')
        want = "scene rds-b: the ground truth reaches"
    else:
        image = np.asarray(stereodepth.io.read_image(last / "right.png"), np.uint16) * 257
        stereodepth.io.write_png16(last / "right.png", image)
        want = (
            "scene rds-b: left and right images must have the same bit depth, got uint8 "
            "(left.png) and uint16 (right.png)"
        )
    status, out, err = run_eval(capsys, str(scenes_dir), "--repeat", "1", "--method", *methods)
    assert status == 2 and out == ""
    assert want in err and err.count("\n") == 1, err
    assert calls == []


def test_find_scenes_checks_its_arguments(scenes_dir: Path) -> None:
    """find_scenes(root, "rds-a") took the str as its characters, and the patterns 'r', 'd',
    's', '-', 'a' matched nothing, while "rds-*" matched every scene through its '*';
    find_scenes("") searched the current folder. Each is refused naming the parameter."""
    assert [s.name for s in find_scenes(scenes_dir, ["rds-a"])] == ["rds-a"]
    with pytest.raises(TypeError, match=r"patterns must be a sequence .* such as \['rds-\*'\]"):
        find_scenes(scenes_dir, "rds-*")
    with pytest.raises(TypeError, match="patterns must be a sequence of shell patterns"):
        find_scenes(scenes_dir, [3])  # type: ignore[list-item]
    with pytest.raises(ValueError, match="root must not be empty"):
        find_scenes("")
    with pytest.raises(TypeError, match=r"root must be a str or os\.PathLike, got int 5"):
        find_scenes(5)  # type: ignore[arg-type]


def test_num_disparities_for_takes_numpy_numbers() -> None:
    """The largest value of a float32 ground truth is a numpy.float32, which was refused as
    'must be a finite number >= 0, got np.float32(5.0)' (so was numpy's int64), while True
    was taken as 1 and 10**400 raised Python's OverflowError naming nothing."""
    assert num_disparities_for(np.float32(5.0)) == 16
    assert num_disparities_for(np.float32(15.5)) == 32
    assert num_disparities_for(np.int64(16)) == 32
    assert num_disparities_for(np.float64(63.0)) == 64
    with pytest.raises(TypeError, match="max_disparity_px must be a real number, got bool True"):
        num_disparities_for(True)
    with pytest.raises(ValueError, match="max_disparity_px must be within the range of a double"):
        num_disparities_for(10**400)


@pytest.mark.parametrize("bad", [-1, math.nan, math.inf])
def test_num_disparities_for_rejects(bad: float) -> None:
    with pytest.raises(ValueError, match=r"^max_disparity_px must be a finite number >= 0"):
        num_disparities_for(bad)


def middlebury_pair(folder: Path, *, rgb: bool) -> tuple[Path, np.ndarray, np.ndarray, np.ndarray]:
    """A 100x40 random-dot scene in Middlebury's layout in ``folder``: im0.png, im1.png and
    disp0GT.pfm (inf where the ground truth is unknown, PFM's convention); returns the folder,
    the images and the ground truth (NaN unknown)."""
    left, right, gt = random_dot_pair(40, 100, [7, 13], rgb=rgb, seed=5)
    folder.mkdir()
    write_png(folder / "im0.png", left)
    write_png(folder / "im1.png", right)
    write_pfm(folder / "disp0GT.pfm", np.where(np.isnan(gt), np.inf, gt).astype(np.float32))
    return folder, left, right, gt


def test_middlebury_layout(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cv2 = pytest.importorskip("cv2")
    folder, left, right, gt = middlebury_pair(tmp_path / "Pair-perfect", rgb=True)
    mask_png = np.full(gt.shape, 255, dtype=np.uint8)
    mask_png[:5] = 128  # occluded in MiddEval3's masks
    write_png(folder / "mask0nocc.png", mask_png)
    (folder / "calib.txt").write_text(
        "cam0=[1000 0 50; 0 1000 20; 0 0 1]\ncam1=[1000 0 50; 0 1000 20; 0 0 1]\n"
        "doffs=0\nbaseline=100\nwidth=100\nheight=40\nndisp=40\n"
    )
    (scene,) = find_scenes(tmp_path)
    assert (scene.name, scene.max_disparity_px) == ("Pair-perfect", 39)
    report = run_json(capsys, str(tmp_path), "--method", "opencv-bm", "--repeat", "1")
    (row,) = report["results"]
    assert row["num_disparities"] == 48
    assert row["region"] == "nonocc"
    want = evaluate(opencv_disparity(cv2, "bm", left, right, 48, 9), gt, mask_png == 255)
    assert_same_metrics(row["metrics"], want.as_dict())
    assert row["metrics"]["evaluated"] == int((np.isfinite(gt) & (mask_png == 255)).sum())


def test_middlebury_calib_of_another_size_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A calib.txt for another resolution (MiddEval3's quarter-size one beside full-size
    images) gave its ndisp, in that resolution's pixels, as the search range: the scene was
    scored with most disparities out of reach, exit status 0. `match` and the web page refuse
    such a calib.txt; eval now does, naming it and both sizes."""
    folder = middlebury_pair(tmp_path / "Pair", rgb=False)[0]
    calib = (
        "cam0=[1000 0 50; 0 1000 20; 0 0 1]\ncam1=[1000 0 50; 0 1000 20; 0 0 1]\n"
        "doffs=0\nbaseline=100\nwidth={w}\nheight={h}\nndisp={n}\n"
    )
    (folder / "calib.txt").write_text(calib.format(w=25, h=10, n=10))
    status, out, err = run_eval(capsys, str(tmp_path))
    assert status == 2 and out == ""
    assert err.count("\n") == 1, err
    assert (
        f"{folder / 'calib.txt'}: it is for 25x10 px images, im0.png is 100x40 px: use the "
        "calib.txt of these images"
    ) in err
    # The calib.txt of these images, and one without a size, are used as before.
    for text in (
        calib.format(w=100, h=40, n=40),
        calib.format(w=100, h=40, n=40).replace("width=100\nheight=40\n", ""),
    ):
        (folder / "calib.txt").write_text(text)
        report = run_json(capsys, str(tmp_path), "--repeat", "1")
        assert report["results"][0]["num_disparities"] == 48


@pytest.mark.parametrize(
    ("mask", "kind"),
    [
        # 65535 is not 255: every pixel was masked out and the scene scored on none of them
        (np.full((40, 100), 65535, np.uint16), "a 16-bit image of shape (40, 100)"),
        (np.full((40, 100, 3), 255, np.uint8), "a colour image of shape (40, 100, 3)"),
    ],
)
def test_middlebury_mask_must_be_8_bit_grey(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], mask: np.ndarray, kind: str
) -> None:
    folder = middlebury_pair(tmp_path / "Pair", rgb=False)[0]
    write_png(folder / "mask0nocc.png", mask)
    status, _, err = run_eval(capsys, str(tmp_path))
    assert status == 2
    assert "mask0nocc.png: a Middlebury mask must be an 8-bit grey PNG" in err and kind in err


# --------------------------------------------------------------------------------------------
# OpenCV methods, checked against an independent run


def test_opencv_bm_matches_direct_run(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cv2 = pytest.importorskip("cv2")
    report = run_json(
        capsys, str(scenes_dir), "--method", "opencv-bm:9,15", "--repeat", "2", "--threads", "1"
    )
    assert report["threads"] == 1
    assert report["repeat"] == 2
    for name, ndisp in (("rds-a", 16), ("rds-b", 32)):
        left, right, gt, mask = load(scenes_dir / name)
        rows = rows_of(report, name, "opencv-bm")
        assert [(r["block_size"], r["best"]) for r in rows[:2]] == [(9, False), (15, False)]
        for row in rows[:2]:
            assert row["num_disparities"] == ndisp
            assert row["region"] == ("nonocc" if mask is not None else "all")
            assert (row["width"], row["height"]) == (gt.shape[1], gt.shape[0])
            d = opencv_disparity(cv2, "bm", left, right, ndisp, row["block_size"])
            assert_same_metrics(row["metrics"], evaluate(d, gt, mask).as_dict())
            # random dots: the pair is fed the right way round, the x16 decoding is right
            assert row["metrics"]["bad_2_est"] < 0.05  # (errors: where the planes meet)
            assert row["metrics"]["density"] > 0.5  # holes: borders of a small image
        best = rows[2]
        assert best["best"] is True
        expected = min(rows[:2], key=lambda r: (r["metrics"]["bad_2"], r["block_size"]))
        assert best["block_size"] == expected["block_size"]
        assert best["metrics"] == expected["metrics"]
    assert len(report["results"]) == 6


def test_opencv_sgbm_matches_direct_run(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cv2 = pytest.importorskip("cv2")
    report = run_json(
        capsys, str(scenes_dir), "--method", "opencv-sgbm", "--repeat", "1", "--scene", "rds-a"
    )
    (row,) = report["results"]
    assert (row["scene"], row["block_size"], row["num_disparities"]) == ("rds-a", 5, 16)
    left, right, gt, mask = load(scenes_dir / "rds-a")
    d = opencv_disparity(cv2, "sgbm", left, right, 16, 5)
    assert_same_metrics(row["metrics"], evaluate(d, gt, mask).as_dict())
    assert row["metrics"]["bad_2_est"] < 0.05


def test_opencv_sgbm_3way_padded_matches_direct_run(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """3WAY on the pair padded on the left by ndisp copies of the first column, cut back: the
    left band that plain 3WAY leaves empty gets disparities."""
    cv2 = pytest.importorskip("cv2")
    methods = ("opencv-sgbm-3way", "opencv-sgbm-3way-padded")
    report = run_json(
        capsys, str(scenes_dir), "--method", *methods, "--repeat", "1", "--scene", "rds-b"
    )
    plain, padded = (rows_of(report, "rds-b", m)[0] for m in methods)
    assert (padded["block_size"], padded["num_disparities"]) == (5, 32)
    left, right, gt, mask = load(scenes_dir / "rds-b")
    mode = {"setMode": cv2.STEREO_SGBM_MODE_SGBM_3WAY}
    pad = ((0, 0), (32, 0))
    d = opencv_disparity(
        cv2, "sgbm", np.pad(left, pad, mode="edge"), np.pad(right, pad, mode="edge"), 32, 5, **mode
    )[:, 32:]
    assert d.shape == gt.shape
    assert_same_metrics(padded["metrics"], evaluate(d, gt, mask).as_dict())
    unpadded = opencv_disparity(cv2, "sgbm", left, right, 32, 5, **mode)
    assert_same_metrics(plain["metrics"], evaluate(unpadded, gt, mask).as_dict())
    # Columns 20..30 have ground truth 20; plain 3WAY leaves its left 31 columns empty.
    assert np.isnan(unpadded[:, :31]).all()
    assert (np.abs(d[3:-3, 22:31] - 20) <= 1).mean() > 0.9
    assert padded["metrics"]["density"] > plain["metrics"]["density"]
    assert padded["metrics"]["bad_2"] < plain["metrics"]["bad_2"]


def test_opencv_option_is_applied(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cv2 = pytest.importorskip("cv2")
    report = run_json(
        capsys,
        str(scenes_dir / "rds-a"),
        "--method",
        "opencv-bm:11",
        "--opencv-option",
        "uniqueness_ratio=60",
        "--opencv-option",
        "texture_threshold=0",
        "--repeat",
        "1",
    )
    (row,) = report["results"]
    left, right, gt, mask = load(scenes_dir / "rds-a")
    d = opencv_disparity(
        cv2, "bm", left, right, 16, 11, setUniquenessRatio=60, setTextureThreshold=0
    )
    plain = opencv_disparity(cv2, "bm", left, right, 16, 11)
    assert np.isnan(d).sum() != np.isnan(plain).sum()  # the option changes the result
    assert_same_metrics(row["metrics"], evaluate(d, gt, mask).as_dict())


def test_block_size_option_and_num_disparities_override(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("cv2")
    report = run_json(
        capsys,
        str(scenes_dir),
        "--method",
        "opencv-bm",
        "opencv-sgbm:3",
        "--block-size",
        "7",
        "--num-disparities",
        "48",
        "--repeat",
        "1",
    )
    got = [
        (r["scene"], r["method"], r["block_size"], r["num_disparities"]) for r in report["results"]
    ]
    assert got == [
        ("rds-a", "opencv-bm", 7, 48),
        ("rds-a", "opencv-sgbm", 3, 48),
        ("rds-b", "opencv-bm", 7, 48),
        ("rds-b", "opencv-sgbm", 3, 48),
    ]


def test_opencv_threads_are_restored(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cv2 = pytest.importorskip("cv2")
    before = cv2.getNumThreads()
    run_json(
        capsys,
        str(scenes_dir / "rds-b"),
        "--method",
        "opencv-bm",
        "--threads",
        "1",
        "--repeat",
        "1",
    )
    assert cv2.getNumThreads() == before


def test_timing_fields(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("cv2")
    report = run_json(capsys, str(scenes_dir), "--method", "opencv-bm", "--repeat", "3")
    for row in report["results"]:
        assert len(row["times_s"]) == 3
        assert all(t > 0 for t in row["times_s"])
        assert row["time_s"] == statistics.median(row["times_s"])
        work = row["width"] * row["height"] * row["num_disparities"]
        assert row["ns_per_px_disparity"] == pytest.approx(row["time_s"] * 1e9 / work)
    (mean,) = report["means"]
    results = report["results"]
    assert mean["scenes"] == 2
    assert mean["time_s"] == pytest.approx(sum(r["time_s"] for r in results) / 2)
    assert mean["ns_per_px_disparity"] == pytest.approx(
        sum(r["time_s"] for r in results)
        * 1e9
        / sum(r["width"] * r["height"] * r["num_disparities"] for r in results)
    )
    for key in ("bad_2", "density", "avgerr"):
        assert mean["metrics"][key] == pytest.approx(sum(r["metrics"][key] for r in results) / 2)


def test_no_mask_scores_all_pixels(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("cv2")
    report = run_json(
        capsys, str(scenes_dir / "rds-a"), "--method", "opencv-bm", "--no-mask", "--repeat", "1"
    )
    (row,) = report["results"]
    _, _, gt, _ = load(scenes_dir / "rds-a")
    assert row["region"] == "all"
    assert row["metrics"]["evaluated"] == int(np.isfinite(gt).sum())


# --------------------------------------------------------------------------------------------
# Tables


def test_markdown_table(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("cv2")
    status, out, _ = run_eval(
        capsys,
        str(scenes_dir),
        "--method",
        "opencv-bm:9,15",
        "opencv-sgbm",
        "--repeat",
        "1",
        "--markdown",
    )
    assert status == 0
    lines = out.strip().splitlines()
    # header, separator, 2 scenes x (bm 9, bm 15, bm best, sgbm 5), 4 mean rows
    assert len(lines) == 2 + 8 + 4
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    assert all(len(c) == len(cells[0]) for c in cells)
    assert cells[0][:3] == ["scene", "method", "block"]
    assert cells[1][:6] == ["---", "---", "---", "---:", "---", "---:"]  # numbers to the right
    assert "bad-2 %" in cells[0]
    assert "ns/(px*d)" in cells[0]
    assert out.isascii()  # a terminal or log in ASCII (PYTHONIOENCODING=ascii) prints it all
    assert [c[2] for c in cells[2:6]] == ["9", "15", cells[4][2], "5"]
    assert cells[4][2] in ("best=9", "best=15")
    assert [(c[0], c[1], c[2]) for c in cells[-4:]] == [
        ("mean", "opencv-bm", "9"),
        ("mean", "opencv-bm", "15"),
        ("mean", "opencv-bm", "best"),
        ("mean", "opencv-sgbm", "5"),
    ]


def test_text_table_matches_json(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("cv2")
    status, out, _ = run_eval(capsys, str(scenes_dir), "--method", "opencv-bm", "--repeat", "1")
    assert status == 0
    report = run_json(capsys, str(scenes_dir), "--method", "opencv-bm", "--repeat", "1")
    lines = out.splitlines()
    assert "threads" in lines[0]
    i = next(i for i, line in enumerate(lines) if line.startswith("scene"))
    spans = [m.span() for m in re.finditer(r"-+", lines[i + 1])]  # the dashes under each title

    def cells(line: str) -> list[str]:
        return [line[a:b].strip() for a, b in spans]

    header = cells(lines[i])
    table = [cells(line) for line in lines[i + 2 :] if line.strip()]
    assert [t[0] for t in table] == ["rds-a", "rds-b", "mean"]
    assert [t[4] for t in table] == ["nonocc", "all", ""]
    for t, row in zip(table, [*report["results"], report["means"][0]], strict=True):
        for title, key in (
            ("bad-2 %", "bad_2"),
            ("density %", "density"),
            ("bad-2(est) %", "bad_2_est"),
            ("D1 %", "d1"),
        ):
            want = 100 * row["metrics"][key]
            assert float(t[header.index(title)]) == pytest.approx(want, abs=0.0051)
        assert float(t[header.index("avgerr px")]) == pytest.approx(
            row["metrics"]["avgerr"], abs=0.0051
        )


def test_tables_are_ascii(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The header said ns/(px\u00b7d): under an ASCII locale or PYTHONIOENCODING=ascii (CI logs,
    # cron) printing the table raised UnicodeEncodeError after every scene had been matched.
    for extra in ((), ("--markdown",)):
        status, out, err = run_eval(
            capsys, str(scenes_dir), "--method", "bm", "--repeat", "1", *extra
        )
        assert status == 0, err
        assert out.isascii() and err.isascii(), [c for c in out + err if not c.isascii()]


# --------------------------------------------------------------------------------------------
# Without OpenCV, and the stereodepth method through a stand-in matcher


def test_opencv_missing_is_reported(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "cv2", None)  # import cv2 raises ImportError
    status, out, err = run_eval(capsys, str(scenes_dir), "--method", "opencv-bm", "opencv-sgbm")
    assert status == 1  # a missing extra, as the README says (it was 2, a usage error)
    assert err.count("\n") == 1
    assert out == ""
    assert "opencv-bm, opencv-sgbm need(s) OpenCV, which is not installed" in err
    assert "pip install opencv-python-headless" in err


def fake_matcher(calls: list[dict[str, Any]]) -> Any:
    """Stands in for stereodepth.matching.StereoMatcher: records the parameters of each
    compute call and returns 0.75 px everywhere but the left quarter (NaN)."""

    class FakeMatcher:
        def __init__(self, **params: Any) -> None:
            self.params = params

        def compute(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
            calls.append({"shape": left.shape, "dtype": left.dtype, **self.params})
            h, w = left.shape[:2]
            d = np.full((h, w), 0.75, dtype=np.float32)
            d[:, : w // 4] = np.nan
            return d

    return FakeMatcher


def test_stereodepth_method_passes_options(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[dict[str, Any]] = []
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher(calls))
    report = run_json(
        capsys,
        str(scenes_dir),
        "--repeat",
        "2",
        "--threads",
        "1",
        "--block-size",
        "7",
        "11",
        "--option",
        "cost=sad",
        "--option",
        "subpixel=false",
        "--option",
        "uniqueness_ratio=12.5",
        "--option",
        "lr_max_diff=none",
        "--option",
        "speckle_window=50",
    )
    # 2 scenes x 2 block sizes x (1 warm-up + 2 timed)
    assert len(calls) == 12
    first = calls[0]
    assert first["shape"] == (64, 128, 3)  # RGB passed straight to the matcher
    assert first["dtype"] == np.uint8
    assert {
        k: first[k]
        for k in (
            "num_disparities",
            "min_disparity",
            "threads",
            "block_size",
            "cost",
            "subpixel",
            "uniqueness_ratio",
            "lr_max_diff",
            "speckle_window",
        )
    } == {
        "num_disparities": 16,
        "min_disparity": 0,
        "threads": 1,
        "block_size": 7,
        "cost": "sad",
        "subpixel": False,
        "uniqueness_ratio": 12.5,
        "lr_max_diff": None,
        "speckle_window": 50,
    }
    assert [c["block_size"] for c in calls] == [7] * 3 + [11] * 3 + [7] * 3 + [11] * 3
    assert calls[6]["num_disparities"] == 32
    for name in ("rds-a", "rds-b"):
        _, _, gt, mask = load(scenes_dir / name)
        d = np.full(gt.shape, 0.75, dtype=np.float32)
        d[:, : gt.shape[1] // 4] = np.nan
        for row in rows_of(report, name, "stereodepth"):
            assert_same_metrics(row["metrics"], evaluate(d, gt, mask).as_dict())


def test_stereodepth_default_block_size_is_named(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[dict[str, Any]] = []
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher(calls))
    report = run_json(capsys, str(scenes_dir / "rds-b"), "--repeat", "1")
    default = inspect.signature(matching.block_match).parameters["block_size"].default
    assert calls[0]["block_size"] == default  # the matcher's own default ...
    assert report["results"][0]["block_size"] == default  # ... named in the results
    assert report["threads"] >= 1
    assert calls[0]["threads"] == report["threads"]
    status, out, _ = run_eval(capsys, str(scenes_dir / "rds-b"), "--repeat", "1", "--markdown")
    assert status == 0
    assert f"| rds-b | stereodepth | {default} | 32 | all |" in out


def test_variants_are_grouped_by_method(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("cv2")
    report = run_json(
        capsys,
        str(scenes_dir / "rds-b"),
        "--method",
        "opencv-bm:9",
        "opencv-sgbm",
        "opencv-bm:15,9",
        "--repeat",
        "1",
    )
    got = [(r["method"], r["block_size"], r["best"]) for r in report["results"]]
    best = min(report["results"][:2], key=lambda r: (r["metrics"]["bad_2"], r["block_size"]))
    assert got == [
        ("opencv-bm", 9, False),
        ("opencv-bm", 15, False),
        ("opencv-bm", best["block_size"], True),
        ("opencv-sgbm", 5, False),
    ]


def test_opencv_missing_skips_only_opencv(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "cv2", None)
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher([]))
    status, out, err = run_eval(
        capsys,
        str(scenes_dir),
        "--method",
        "stereodepth",
        "opencv-bm",
        "--repeat",
        "1",
        "--markdown",
    )
    assert status == 0
    assert "skipped opencv-bm: OpenCV is not installed" in err
    assert "stereodepth" in out
    assert "opencv" not in out


def test_matcher_errors_name_the_scene(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A block size no cost allows is refused before any scene is read (as sgm:5 is)...
    for args in (["--block-size", "4"], ["--method", "stereodepth:4"]):
        status, _, err = run_eval(capsys, str(scenes_dir), *args)
        assert status == 2
        assert err == (
            "stereodepth eval: error: block size of stereodepth must be an odd integer in "
            "3..63, got 4\n"
        )
    # ... and one only the options make wrong (SAD costs allow 31 at most) names the scene.
    status, _, err = run_eval(capsys, str(scenes_dir), "--block-size", "33", "--option", "cost=sad")
    assert status == 2
    assert err.startswith("stereodepth eval: error: scene rds-a: stereodepth: block_size must ")
    assert "got 33" in err
    assert err.count("\n") == 1


# --------------------------------------------------------------------------------------------
# The real matcher


def test_stereodepth_matches_direct_run(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    block_match = stereodepth.block_match
    report = run_json(capsys, str(scenes_dir), "--repeat", "1", "--threads", "2")
    for name, ndisp in (("rds-a", 16), ("rds-b", 32)):
        left, right, gt, mask = load(scenes_dir / name)
        (row,) = rows_of(report, name, "stereodepth")
        assert row["num_disparities"] == ndisp
        d = block_match(left, right, num_disparities=ndisp, min_disparity=0, threads=2)
        assert_same_metrics(row["metrics"], evaluate(d, gt, mask).as_dict())
        # random dots: fed the right way round
        assert row["metrics"]["bad_2_est"] < 0.05
        assert row["metrics"]["density"] > 0.5


# --------------------------------------------------------------------------------------------
# The shared scenes (a small subset, so that it stays quick)


@pytest.mark.data
def test_shared_scene_opencv(stereo_data_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cv2 = pytest.importorskip("cv2")
    report = run_json(
        capsys,
        str(stereo_data_dir),
        "--scene",
        "mb2001-tsukuba",
        "--method",
        "opencv-bm:9,15",
        "opencv-sgbm",
        "--repeat",
        "1",
        "--threads",
        "2",
    )
    folder = stereo_data_dir / "mb2001-tsukuba"
    meta = json.loads((folder / "meta.json").read_text())
    left, right = (stereodepth.io.read_image(folder / n) for n in ("left.png", "right.png"))
    gt, mask = np.load(folder / "disp_gt.npy"), np.load(folder / "mask_nonocc.npy")
    ndisp = 16 * math.ceil((meta["max_disp"] + 1) / 16)
    rows = report["results"]
    assert [(r["method"], r["block_size"], r["best"]) for r in rows][:2] == [
        ("opencv-bm", 9, False),
        ("opencv-bm", 15, False),
    ]
    for row in rows:
        assert (row["num_disparities"], row["region"]) == (ndisp, "nonocc")
        kind = "bm" if row["method"] == "opencv-bm" else "sgbm"
        d = opencv_disparity(cv2, kind, left, right, ndisp, row["block_size"])
        assert_same_metrics(row["metrics"], evaluate(d, gt, mask).as_dict())
    sgbm = rows_of(report, "mb2001-tsukuba", "opencv-sgbm")[0]["metrics"]
    assert sgbm["bad_2"] < 0.10  # SGBM is known to get ~5 % on Tsukuba


@pytest.mark.data
def test_shared_scene_stereodepth(
    stereo_data_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    block_match = stereodepth.block_match
    report = run_json(
        capsys,
        str(stereo_data_dir),
        "--scene",
        "mb2001-tsukuba",
        "--scene",
        "mb2003-cones",
        "--repeat",
        "1",
        "--threads",
        "2",
    )
    assert [r["scene"] for r in report["results"]] == ["mb2001-tsukuba", "mb2003-cones"]
    for row in report["results"]:
        folder = stereo_data_dir / row["scene"]
        left, right = (stereodepth.io.read_image(folder / n) for n in ("left.png", "right.png"))
        gt, mask = np.load(folder / "disp_gt.npy"), np.load(folder / "mask_nonocc.npy")
        d = block_match(left, right, num_disparities=row["num_disparities"], threads=2)
        assert_same_metrics(row["metrics"], evaluate(d, gt, mask).as_dict())
        assert row["metrics"]["bad_4"] < 0.5  # a working matcher, not noise


# --------------------------------------------------------------------------------------------
# Rejected input: one test each


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--repeat", "0"], "--repeat must be an integer >= 1, got 0"),
        (
            ["--threads", "-1"],
            "--threads must be an integer >= 0 and <= 2147483647 (0: every core), got -1",
        ),
        # Beyond a C int it was the matcher's "threads must be ...", after reading the scene.
        (
            ["--threads", str(2**31)],
            "--threads must be an integer >= 0 and <= 2147483647 (0: every core), got 2147483648",
        ),
        (
            ["--num-disparities", "20"],
            "--num-disparities must be a positive multiple of 16 and <= 4096, got 20",
        ),
        # No upper bound: the matcher's "num_disparities must be ..." (OpenCV's "integer
        # won't fit into a C int"), once a scene was read.
        (
            ["--num-disparities", str(2**56)],
            f"--num-disparities must be a positive multiple of 16 and <= 4096, got {2**56}",
        ),
        (
            ["--num-disparities", "4112"],
            "--num-disparities must be a positive multiple of 16 and <= 4096, got 4112",
        ),
        (
            ["--method", "opencv-bm:4"],
            "block size of opencv-bm must be an odd integer in 5..255, got 4",
        ),
        (
            ["--method", "opencv-sgbm:6"],
            "block size of opencv-sgbm must be an odd integer in 1..8191 (eval gives OpenCV P2",
        ),
        (["--option", "threads=3"], "--option threads: use --threads"),
        (["--option", "num_disparities=64"], "--option num_disparities: set per scene"),
        (
            ["--method", "opencv-bm", "--option", "cost=sad"],
            "--option is for stereodepth.block_match: add --method stereodepth",
        ),
        (["--scene", "nothing*"], "--scene nothing* matches no scene in"),
        (
            ["--method", "stereodepth", "--sgm-option", "paths=8"],
            "--sgm-option is for stereodepth.semi_global_match: add --method sgm",
        ),
        (["--method", "sgm", "--sgm-option", "paths=5"], "--sgm-option paths=5: paths must be"),
        (["--method", "sgm", "--sgm-option", "cost=sad"], "--sgm-option cost: sgm's matcher has"),
        (["--method", "sgm", "--sgm-option", "threads=1"], "--sgm-option threads: use --threads"),
    ],
)
def test_rejected_arguments(
    scenes_dir: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    message: str,
) -> None:
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher([]))
    status, out, err = run_eval(capsys, str(scenes_dir), *argv)
    assert status == 2
    assert out == ""
    assert err.startswith("stereodepth eval: error: ")
    assert message in err


def test_rejects_unknown_opencv_option(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("cv2")
    status, _, err = run_eval(
        capsys, str(scenes_dir), "--method", "opencv-bm", "--opencv-option", "nonsense_knob=1"
    )
    assert status == 2
    assert "--opencv-option nonsense_knob: no selected OpenCV matcher has setNonsenseKnob()" in err


@pytest.mark.parametrize(
    ("flag", "method"),
    [("--option", "stereodepth"), ("--sgm-option", "sgm"), ("--opencv-option", "opencv-bm")],
)
def test_an_option_given_twice_is_a_usage_error(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], flag: str, method: str
) -> None:
    """The last value was used without a word (as batch's --option had it). The parser
    refuses it (cli.KeyValueOnce), so argparse exits."""
    with pytest.raises(SystemExit) as info:
        cli.main([
            "eval", str(scenes_dir), "--method", method, flag, "uniqueness_ratio=5",
            flag, "uniqueness_ratio=10",
        ])  # fmt: skip
    status = info.value.code
    out, err = capsys.readouterr()
    assert (status, out) == (2, "")
    assert err.count("\n") == 1
    assert f"{flag} uniqueness_ratio is given twice (5 and 10): give it once" in err


def test_rejects_opencv_option_value(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("cv2")
    status, _, err = run_eval(
        capsys, str(scenes_dir), "--method", "opencv-bm", "--opencv-option", "uniqueness_ratio=abc"
    )
    assert status == 2
    assert "--opencv-option uniqueness_ratio=abc rejected by opencv-bm" in err


@pytest.mark.parametrize(
    "argv",
    [
        ["--method", "opencv-xyz"],
        ["--method", "opencv-bm:9,x"],
        ["--option", "no-equals-sign"],
        ["--json", "--markdown"],
        ["--best-by", "speed"],
    ],
)
def test_rejected_by_the_parser(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(["eval", str(scenes_dir), *argv])
    assert info.value.code == 2
    assert "stereodepth eval: error:" in capsys.readouterr().err


def test_rejects_missing_dir(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    status, _, err = run_eval(capsys, str(tmp_path / "nowhere"))
    assert status == 2
    assert "DIR must be a folder of scenes, got" in err
    assert "nowhere" in err


def test_rejects_dir_without_scenes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "empty").mkdir()
    status, _, err = run_eval(capsys, str(tmp_path))
    assert status == 2
    assert "no scene in" in err
    assert "left.png, right.png and disp_gt.npy" in err


def test_rejects_bad_meta(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (scenes_dir / "rds-a" / "meta.json").write_text('{"max_disp": "big"}')
    status, _, err = run_eval(capsys, str(scenes_dir))
    assert status == 2
    assert "meta.json: max_disp must be a finite number >= 0, got 'big'" in err


@pytest.mark.parametrize(
    ("text", "message"),
    [
        # A JSON integer beyond a double's range was a traceback (OverflowError in float()),
        # Infinity an error that did not name the file, and a list was read as no max_disp.
        ('{"max_disp": 1' + "0" * 400 + "}", "max_disp must be a finite number >= 0, got 1000"),
        ('{"max_disp": Infinity}', "max_disp must be a finite number >= 0, got inf"),
        ('{"max_disp": NaN}', "max_disp must be a finite number >= 0, got nan"),
        ("[11]", "meta.json: must be a JSON object, got list"),
    ],
)
def test_rejects_meta_out_of_range(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], text: str, message: str
) -> None:
    (scenes_dir / "rds-a" / "meta.json").write_text(text)
    status, _, err = run_eval(capsys, str(scenes_dir))
    assert status == 2
    assert message in err and "meta.json" in err
    assert len(err.strip().splitlines()) == 1


def test_a_search_range_beyond_the_matchers_names_its_source(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The matcher's "num_disparities must be an integer in [1, 4096], got 5008" named the
    # scene but not where 5008 came from, nor what to do.
    (scenes_dir / "rds-a" / "meta.json").write_text('{"max_disp": 5000}')
    status, _, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-a")
    assert status == 2
    assert (
        "scene rds-a: meta.json's max_disp=5000 needs 5008 disparities, more than the "
        "matchers search (4096): give --num-disparities"
    ) in err


def test_a_declared_range_the_ground_truth_leaves_is_refused(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A meta.json max_disp (or calib.txt ndisp) smaller than the ground truth's disparities
    (one of another resolution) made every method search a range the truth leaves: the
    scene was scored badly for every method, exit status 0. Refused naming the scene, the
    largest true disparity, the range and its source; --num-disparities still decides."""
    gt = np.load(scenes_dir / "rds-b" / "disp_gt.npy")
    top = float(np.nanmax(gt))
    assert top > 15
    (scenes_dir / "rds-b" / "meta.json").write_text('{"max_disp": 3}')
    status, out, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-b")
    assert status == 2 and out == ""
    assert err.count("\n") == 1, err
    assert (
        f"scene rds-b: the ground truth reaches {top:g} px ({int((gt > 15).sum())} pixels "
        "beyond the search range 0 .. 15 that meta.json's max_disp=3 gives): correct it, or "
        "give --num-disparities"
    ) in err
    report = run_json(capsys, str(scenes_dir), "--scene", "rds-b", "--num-disparities", "16")
    assert report["results"][0]["num_disparities"] == 16


def test_rejects_unreadable_meta(scenes_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (scenes_dir / "rds-a" / "meta.json").write_text("{not json")
    status, _, err = run_eval(capsys, str(scenes_dir))
    assert status == 2
    assert "meta.json: cannot read JSON" in err


def test_rejects_mismatched_pair(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher([]))
    write_png(scenes_dir / "rds-b" / "right.png", np.zeros((64, 149), dtype=np.uint8))
    status, _, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-b")
    assert status == 2
    assert (
        "scene rds-b: left and right images must have the same shape, got (64, 150) and (64, 149)"
    ) in err


def test_rejects_gt_of_wrong_shape(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher([]))
    np.save(scenes_dir / "rds-b" / "disp_gt.npy", np.zeros((64, 151), dtype=np.float32))
    status, _, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-b")
    assert status == 2
    assert (
        "disp_gt.npy: ground truth must be a float array of the image's shape (64, 150), "
        "got float32 (64, 151)"
    ) in err


def test_rejects_non_bool_mask(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher([]))
    np.save(scenes_dir / "rds-a" / "mask_nonocc.npy", np.ones((64, 128), dtype=np.uint8))
    status, _, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-a")
    assert status == 2
    assert (
        "mask_nonocc.npy: mask must be a bool array of the image's shape (64, 128), "
        "got uint8 (64, 128)"
    ) in err


def test_rejects_negative_gt_naming_the_file(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # A ground truth with -5 in it was scored silently.
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher([]))
    gt = np.full((64, 150), 4.0, dtype=np.float32)
    gt[3, 7] = -5.0
    np.save(scenes_dir / "rds-b" / "disp_gt.npy", gt)
    status, out, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-b")
    assert status == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1
    assert (
        "disp_gt.npy: ground truth must be >= 0 where it is finite (KITTI and Middlebury have no "
        "negative disparity; mark unknown pixels with NaN or inf, and decode KITTI's 0 to NaN), "
        "got -5.0 at row 3, column 7 (1 negative pixel)"
    ) in lines[0]


def test_rejects_gt_without_values(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher([]))
    np.save(scenes_dir / "rds-b" / "disp_gt.npy", np.full((64, 150), np.nan, dtype=np.float32))
    status, _, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-b")
    assert status == 2
    assert "scene rds-b: the ground truth has no finite value" in err


@pytest.mark.parametrize("with_meta", [False, True])
def test_rejects_a_scene_with_nothing_to_score(
    scenes_dir: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    with_meta: bool,
) -> None:
    # An all-False mask, or an all-NaN ground truth beside a meta.json max_disp, gave a row
    # of dashes and exit status 0.
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher([]))
    scene = scenes_dir / "rds-a"
    if with_meta:
        (scene / "meta.json").write_text('{"max_disp": 12}')
        np.save(scene / "disp_gt.npy", np.full((64, 128), np.nan, dtype=np.float32))
        want = "scene rds-a: the ground truth has no finite value"
    else:
        np.save(scene / "mask_nonocc.npy", np.zeros((64, 128), dtype=bool))
        known = int(np.isfinite(np.load(scene / "disp_gt.npy")).sum())
        want = f"mask_nonocc.npy: the mask selects none of the {known} pixels with ground truth"
    status, out, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-a")
    assert status == 2 and out == ""
    assert want in err and len(err.strip().splitlines()) == 1
    if not with_meta:
        status, _, _ = run_eval(capsys, str(scenes_dir), "--scene", "rds-a", "--no-mask")
        assert status == 0


def test_sgm_method_passes_its_options(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """--sgm-option reaches the semi-global matcher (and only it): the scores equal those of
    semi_global_match with the same options."""
    from stereodepth import semi_global

    argv = ["--method", "sgm", "stereodepth", "--threads", "1", "--sgm-option", "paths=8"]
    argv += ["--sgm-option", "p2=300", "--sgm-option", "fill=true"]
    report = run_json(capsys, str(scenes_dir), *argv)
    row = next(r for r in report["results"] if r["method"] == "sgm" and r["scene"] == "rds-a")
    left, right, gt, mask = load(scenes_dir / "rds-a")
    direct = stereodepth.semi_global_match(
        left, right, num_disparities=row["num_disparities"], threads=1, paths=8, p2=300,
        fill=True,
    )  # fmt: skip
    assert row["metrics"]["bad_2"] == evaluate(direct, gt, mask).bad_2
    calls: list[dict[str, Any]] = []
    monkeypatch.setattr(semi_global, "SemiGlobalMatcher", fake_matcher(calls))
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher(calls))
    run_json(capsys, str(scenes_dir), *argv)
    sgm_calls = [c for c in calls if "paths" in c]
    assert sgm_calls and all((c["paths"], c["p2"], c["fill"]) == (8, 300, True) for c in sgm_calls)
    assert len(sgm_calls) < len(calls)  # the block matcher got none of them


def test_json_report_records_the_matcher_options(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two reports of the same methods with different options must tell which is which."""
    argv = ["--method", "sgm", "stereodepth", "--threads", "1", "--scene", "rds-a"]
    argv += ["--sgm-option", "paths=8", "--sgm-option", "fill=true", "--sgm-option", "p2=300"]
    argv += ["--option", "cost=sad", "--option", "lr_max_diff=none"]
    report = run_json(capsys, str(scenes_dir), *argv)
    assert report["sgm_options"] == {"paths": 8, "fill": True, "p2": 300}
    assert report["options"] == {"cost": "sad", "lr_max_diff": None}
    assert report["opencv_options"] == {}
    plain = run_json(capsys, str(scenes_dir), "--threads", "1", "--scene", "rds-a")
    assert (plain["options"], plain["sgm_options"], plain["opencv_options"]) == ({}, {}, {})


def test_time_ratios_are_medians_over_shared_scenes() -> None:
    from stereodepth.evaluation import EvalResult, Variant, format_time_ratios, time_ratios

    gt = np.ones((4, 4), dtype=np.float32)
    metrics = evaluate(gt, gt)
    ours, bm = Variant("stereodepth", 9), Variant("opencv-bm", 9)

    def row(scene: str, variant: Variant, t: float, best: bool = False) -> EvalResult:
        return EvalResult(scene, variant, 16, 4, 4, "all", metrics, (t, 99.0, t), best=best)

    rows = [
        row("a", ours, 1.0),
        row("a", bm, 4.0),
        row("a", bm, 4.0, best=True),  # copies of best rows are not counted twice
        row("b", ours, 3.0),
        row("b", bm, 2.0),
        row("c", ours, 1.0),
        row("c", bm, 5.0),
        row("d", bm, 1.0),  # no stereodepth run on d
    ]
    (ratio,) = time_ratios(rows)
    assert ratio["per_scene"] == {"a": 0.25, "b": 1.5, "c": 0.2}
    assert ratio["median"] == 0.25
    assert format_time_ratios(rows) == (
        "time of stereodepth (block 9) / opencv-bm (block 9), median over 3 scene(s): 0.250"
    )
    # sgm is ours too (no block size to name), compared with the peers, not with stereodepth.
    sgm = Variant("sgm", None)
    rows += [row("a", sgm, 2.0), row("b", sgm, 1.0)]
    assert format_time_ratios(rows).splitlines() == [
        "time of stereodepth (block 9) / opencv-bm (block 9), median over 3 scene(s): 0.250",
        "time of sgm / opencv-bm (block 9), median over 2 scene(s): 0.500",
    ]


def test_time_ratio_lines_follow_the_table(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("cv2")
    status, out, _ = run_eval(capsys, str(scenes_dir), "--method", "stereodepth", "opencv-bm:9")
    assert status == 0
    assert re.search(
        r"\ntime of stereodepth \(block 9\) / opencv-bm \(block 9\), median over 2 scene\(s\): "
        r"\d+\.\d{3}\n$",
        out,
    )


@pytest.mark.data
@pytest.mark.slow
def test_issue_11_accuracy_targets_on_the_shared_scenes(
    stereo_data_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """sgm with its defaults, over the ten shared scenes (bench/README.md, "Semi-global
    matching"): mean bad-2 at most 0.7x SGBM 3WAY's and below 3WAY's on the left-padded pair;
    mean bad-0.5 among estimated pixels below 3WAY's."""
    pytest.importorskip("cv2")
    scenes = sorted(p.name for p in stereo_data_dir.iterdir() if (p / "disp_gt.npy").is_file())
    if len(scenes) < 10:
        pytest.skip(f"the ten shared scenes are not all in {stereo_data_dir}")
    methods = ("sgm", "opencv-sgbm-3way", "opencv-sgbm-3way-padded")
    report = run_json(
        capsys, str(stereo_data_dir), "--method", *methods, "--repeat", "1", "--threads", "2"
    )
    means = {m["method"]: m["metrics"] for m in report["means"]}
    for m in methods:
        assert sum(r["method"] == m for r in report["results"]) == len(scenes)
    ours, three_way, padded = (means[m] for m in methods)
    assert ours["bad_2"] <= 0.7 * three_way["bad_2"]
    assert ours["bad_2"] < padded["bad_2"]
    assert ours["bad_0_5_est"] < three_way["bad_0_5_est"]


def test_bm_is_block_matching_as_in_match_and_batch(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[dict[str, Any]] = []
    monkeypatch.setattr(matching, "StereoMatcher", fake_matcher(calls))
    report = run_json(
        capsys, str(scenes_dir / "rds-b"), "--method", "bm:7", "--repeat", "1", "--option",
        "cost=sad",
    )  # fmt: skip
    assert [(r["method"], r["block_size"]) for r in report["results"]] == [("stereodepth", 7)]
    assert calls and all(c["block_size"] == 7 and c["cost"] == "sad" for c in calls)


@pytest.mark.parametrize(
    ("name", "content", "fragment"),
    [
        ("disp_gt.npy", b"", "disp_gt.npy: not a readable .npy array (No data left in file)"),
        # numpy took it for a pickle ("This file contains pickled (object) data").
        ("disp_gt.npy", b"hello\n", "disp_gt.npy: not a readable .npy array (no NumPy header"),
        ("mask_nonocc.npy", b"\x93NUMPY\x01\x00", "mask_nonocc.npy: not a readable .npy array"),
    ],
)
def test_unreadable_npy_is_one_line_naming_the_file(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], name: str, content: bytes, fragment: str
) -> None:
    """An empty .npy raised EOFError (a traceback); numpy's other messages named no file."""
    (scenes_dir / "rds-a" / name).write_bytes(content)
    status, out, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-a", "--method", "bm")
    assert status == 2 and out == "", err
    assert err.count("\n") == 1 and err.startswith("stereodepth eval: error: "), err
    assert str(scenes_dir / "rds-a" / fragment) in err, err


@pytest.mark.parametrize("layout", ["ours", "middlebury"])
def test_a_scene_folder_without_its_right_image_is_refused_up_front(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], layout: str
) -> None:
    """A folder with a scene's left image and ground truth but no right image was taken as a
    scene, and the run failed on it with exit status 1 after matching the scenes before it."""
    folder = scenes_dir / "zz-incomplete"
    folder.mkdir()
    left, _, gt = random_dot_pair(32, 64, [5], rgb=False, seed=3)
    if layout == "ours":
        write_png(folder / "left.png", left)
        np.save(folder / "disp_gt.npy", gt)
        missing, gt_name = "right.png", "disp_gt.npy"
    else:
        write_png(folder / "im0.png", left)
        write_pfm(folder / "disp0GT.pfm", gt)
        missing, gt_name = "im1.png", "disp0GT.pfm"
    status, out, err = run_eval(capsys, str(scenes_dir), "--repeat", "1")
    assert status == 2 and out == ""
    assert f"holds {'left.png' if layout == 'ours' else 'im0.png'} and {gt_name} but not " in err
    assert f"not {missing}: a scene folder holds all three" in err and err.count("\n") == 1
    with pytest.raises(ValueError, match=f"but not {missing}"):
        find_scenes(scenes_dir)


# --------------------------------------------------------------------------------------------
# --scene reads and checks the selected scenes only


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        ("meta", "meta.json: max_disp must be a finite number >= 0, got inf"),
        ("calib", "calib.txt"),
        ("right", "holds left.png and disp_gt.npy but not right.png"),
    ],
)
def test_a_broken_scene_left_out_by_scene_does_not_matter(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str], fault: str, message: str
) -> None:
    """Every scene's meta.json (calib.txt, right image) was read and checked whatever --scene
    said: a broken scene left out ended the run (exit status 2). Selected, it still does,
    with the same error as without --scene."""
    broken = scenes_dir / "zz-broken"
    if fault == "calib":
        _, left, right, gt = middlebury_pair(broken, rgb=False)
        (broken / "calib.txt").write_text("ndisp=many\n")
    else:
        left, right, gt = random_dot_pair(32, 64, [4], rgb=False, seed=5)
        write_scene(broken, left, right, gt)
        if fault == "meta":
            (broken / "meta.json").write_text('{"max_disp": 1e400}')
        else:
            (broken / "right.png").unlink()
    status, _, err = run_eval(capsys, str(scenes_dir))
    assert status == 2 and message in err and err.count("\n") == 1, err
    for patterns in (["rds-b"], ["rds-*"], ["rds-a", "rds-b"]):
        argv = [a for p in patterns for a in ("--scene", p)]
        report = run_json(capsys, str(scenes_dir), *argv, "--repeat", "1")
        assert report["scenes"] == [s for s in ("rds-a", "rds-b") if s in report["scenes"]]
        assert len(report["scenes"]) == (1 if patterns == ["rds-b"] else 2)
    for patterns in (["zz-*"], ["rds-b", "zz-broken"]):
        argv = [a for p in patterns for a in ("--scene", p)]
        assert run_eval(capsys, str(scenes_dir), *argv, "--repeat", "1") == (2, "", err)


def test_scene_matching_nothing_lists_every_scene_without_reading_them(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    left, right, gt = random_dot_pair(32, 64, [4], rgb=False, seed=5)
    write_scene(scenes_dir / "zz-broken", left, right, gt, meta={"max_disp": -1})
    status, out, err = run_eval(capsys, str(scenes_dir), "--scene", "nothing*")
    assert (status, out) == (2, "")
    assert err == (
        f"stereodepth eval: error: --scene nothing* matches no scene in {str(scenes_dir)!r}; "
        "there are: rds-a, rds-b, zz-broken\n"
    )


# --------------------------------------------------------------------------------------------
# Counts in messages: 1 pixel, 2 pixels


def test_one_pixel_beyond_the_declared_range_is_singular(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It read "1 pixels beyond the search range"."""
    gt = np.load(scenes_dir / "rds-b" / "disp_gt.npy")
    gt[np.isfinite(gt)] = 3.0
    gt[0, -1] = 20.0
    np.save(scenes_dir / "rds-b" / "disp_gt.npy", gt)
    (scenes_dir / "rds-b" / "meta.json").write_text('{"max_disp": 3}')
    status, _, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-b")
    assert status == 2
    assert "the ground truth reaches 20 px (1 pixel beyond the search range 0 .. 15 " in err, err
    gt[0, -2] = 20.0
    np.save(scenes_dir / "rds-b" / "disp_gt.npy", gt)
    status, _, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-b")
    assert "the ground truth reaches 20 px (2 pixels beyond the search range 0 .. 15 " in err, err


def test_a_mask_leaving_out_the_only_pixel_with_ground_truth(
    scenes_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It read "the mask selects none of the 1 pixels with ground truth"."""
    scene = scenes_dir / "rds-a"
    gt = np.full((64, 128), np.nan, np.float32)
    gt[10, 20] = 5.0
    np.save(scene / "disp_gt.npy", gt)
    mask = np.ones((64, 128), bool)
    mask[10, 20] = False
    np.save(scene / "mask_nonocc.npy", mask)
    status, out, err = run_eval(capsys, str(scenes_dir), "--scene", "rds-a")
    assert (status, out) == (2, "")
    assert err.endswith(
        "mask_nonocc.npy: the mask leaves out the only pixel with ground truth (--no-mask "
        "scores it)\n"
    ), err
