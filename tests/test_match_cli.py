"""``stereodepth match`` end to end on shared scenes (skipped when absent) and on the package's
own sample pair: the files, their formats, the previews, the depth equal to the library's, the
summary; and every kind of bad input: one line, exit status 2, no traceback."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("PIL", reason="reading images needs Pillow (the batch extra)")
pytest.importorskip("matplotlib", reason="the previews need the plot extra")

from PIL import Image

import stereodepth
from stereodepth import block_match, colorize, disparity_to_depth, reproject
from stereodepth.cli import main
from stereodepth.colormap import COLORBAR_HEIGHT_PX
from stereodepth.io import read_disparity_pfm, read_image, read_pfm
from stereodepth.match_pair import default_num_disparities, sgm_available
from stereodepth.sample import sample_pair

PIANO = {"focal_px": 713.189, "baseline_mm": 178.089, "doffs_px": 31.34, "ndisp": 73}


def outputs(folder: Path) -> list[str]:
    """The files in ``folder`` but match's record of its last run (.stereodepth-match.json)."""
    return sorted(p.name for p in folder.iterdir() if not p.name.endswith("stereodepth-match.json"))


def write_middlebury_calib(path: Path, w: int, h: int) -> Path:
    f, d = PIANO["focal_px"], PIANO["doffs_px"]
    path.write_text(
        f"cam0=[{f} 0 276.193; 0 {f} 242.587; 0 0 1]\n"
        f"cam1=[{f} 0 {276.193 + d}; 0 {f} 242.587; 0 0 1]\n"
        f"doffs={d}\nbaseline={PIANO['baseline_mm']}\nwidth={w}\nheight={h}\n"
        f"ndisp={PIANO['ndisp']}\nisint=0\nvmin=0\nvmax=60\n"
    )
    return path


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["match", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal bit for bit, NaN where NaN."""
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.fixture
def piano(stereo_data_dir: Path) -> Path:
    p = stereo_data_dir / "mb2014q-piano"
    if not p.is_dir():
        pytest.skip("mb2014q-piano not in the shared data")
    return p


@pytest.mark.data
def test_middlebury_calib_folder_outputs(
    piano: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    left, right = read_image(piano / "left.png"), read_image(piano / "right.png")
    h, w = left.shape[:2]
    calib = write_middlebury_calib(tmp_path / "calib.txt", w, h)
    out = tmp_path / "out"
    code, text, err = run(
        capsys,
        piano / "left.png",
        piano / "right.png",
        "--calib",
        calib,
        "-o",
        f"{out}/",
        "--ply",
        "--json",
    )
    assert code == 0, err
    s = json.loads(text)
    names = outputs(out)
    assert names == sorted(
        ["disparity.pfm", "depth.npy", "disparity-preview.png", "depth-preview.png", "points.ply"]
    )
    # The disparity is the library's block matcher with Middlebury's ndisp.
    disparity = read_disparity_pfm(out / "disparity.pfm")
    assert same(disparity, block_match(left, right, num_disparities=PIANO["ndisp"]))
    # On disk, Middlebury's convention: +inf where there is no disparity.
    assert np.array_equal(read_pfm(out / "disparity.pfm") == np.inf, np.isnan(disparity))
    # The depth is disparity_to_depth of that disparity with the calibration, bit for bit.
    depth = np.load(out / "depth.npy")
    expected = disparity_to_depth(
        disparity,
        focal_px=PIANO["focal_px"],
        baseline_m=PIANO["baseline_mm"] / 1000,
        doffs_px=PIANO["doffs_px"],
    )
    assert same(depth, expected)
    y, x = 300, 400  # a pixel on the piano
    assert (
        np.isfinite(depth[y, x])
        and depth[y, x]
        == disparity_to_depth(
            disparity[y : y + 1, x : x + 1],
            focal_px=PIANO["focal_px"],
            baseline_m=PIANO["baseline_mm"] / 1000,
            doffs_px=PIANO["doffs_px"],
        )[0, 0]
    )
    # Previews: RGB PNGs, the map pixel for pixel over a colour bar.
    for name, values in (("disparity", disparity), ("depth", depth)):
        with Image.open(out / f"{name}-preview.png") as im:
            assert im.mode == "RGB" and im.size == (w, h + COLORBAR_HEIGHT_PX)
            assert np.asarray(im)[:h].tolist() == colorize(values).tolist()
    # The summary.
    assert (s["width"], s["height"], s["method"]) == (w, h, "bm")
    assert s["num_disparities"] == PIANO["ndisp"]
    assert s["density"] == float(np.isfinite(disparity).mean())
    finite = depth[np.isfinite(depth)]
    assert s["depth_range_m"] == [float(finite.min()), float(finite.max())]
    assert s["time_s"] > 0 and s["calibration"] == str(calib)
    assert s["outputs"]["ply"] == str(out / "points.ply")
    head = (out / "points.ply").read_bytes()[:400].decode("ascii", "replace")
    points = reproject(
        disparity,
        focal_px=PIANO["focal_px"],
        baseline_m=PIANO["baseline_mm"] / 1000,
        doffs_px=PIANO["doffs_px"],
        cx_px=276.193,
        cy_px=242.587,
    )
    n = int(np.isfinite(points).all(axis=-1).sum())
    assert f"element vertex {n}\n" in head and "property uchar red" in head


@pytest.mark.data
def test_kitti_rig_on_the_command_line_prefix_and_png16(
    stereo_data_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = stereo_data_dir / "kitti2012-000070"
    if not scene.is_dir():
        pytest.skip("kitti2012-000070 not in the shared data")
    rig = ["--focal-px", "718.856", "--baseline-mm", "537.166"]
    code, text, err = run(
        capsys,
        scene / "left.png",
        scene / "right.png",
        *rig,
        "--num-disparities",
        "160",
        "--disparity-format",
        "png16",
        "--depth-format",
        "png16",
        "--no-preview",
        "-o",
        tmp_path / "k-",
    )
    assert code == 0, err
    assert outputs(tmp_path) == ["k-depth.png", "k-disparity.png"]
    left, right = read_image(scene / "left.png"), read_image(scene / "right.png")
    d = block_match(left, right, num_disparities=160)
    got_d = read_image(tmp_path / "k-disparity.png")
    ok = np.isfinite(d) & (d > 0)
    assert got_d.dtype == np.uint16
    assert (got_d[~ok] == 0).all()
    # KITTI's devkit rounds half up (io.write_disparity_png16); d * 256 + 0.5 is exact here.
    want = np.minimum(np.floor(d[ok].astype(np.float64) * 256 + 0.5), 65535)
    assert np.array_equal(got_d[ok], want)
    mm = disparity_to_depth(d, focal_px=718.856, baseline_m=0.537166, dtype=np.uint16)
    assert np.array_equal(read_image(tmp_path / "k-depth.png"), mm)
    assert "density" in text and "depth" in text and "from command line" in text


def test_sample_pair_without_a_rig_writes_the_disparity_only(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = sample_pair(160, 120)
    Image.fromarray(s.left).save(tmp_path / "l.png")
    Image.fromarray(s.right).convert("L").save(tmp_path / "r.png")
    # A colour left with a grey right is refused, as block_match and batch refuse it.
    code, _, err = run(capsys, tmp_path / "l.png", tmp_path / "r.png", "-o", f"{tmp_path}/x/")
    assert code == 2
    assert err.strip().endswith(
        "right must be colour (RGB) as left is, got a grey image "
        "(convert one of them: both colour or both grey)"
    )
    Image.fromarray(s.left).convert("L").save(tmp_path / "l.png")
    code, text, err = run(
        capsys,
        tmp_path / "l.png",
        tmp_path / "r.png",
        "-o",
        f"{tmp_path / 'o'}/",
        "--disparity-format",
        "npy",
    )
    assert code == 0, err
    assert outputs(tmp_path / "o") == [
        "disparity-preview.png",
        "disparity.npy",
    ]
    d = np.load(tmp_path / "o" / "disparity.npy")
    lg, rg = read_image(tmp_path / "l.png"), read_image(tmp_path / "r.png")
    assert same(d, block_match(lg, rg, num_disparities=default_num_disparities(160)))
    ok = np.isfinite(d)
    assert np.mean(np.abs(d[ok] - s.disparity[ok]) <= 1) > 0.95  # the known disparity
    assert "no rig: give --calib" in text


def test_kitti_calib_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    s = sample_pair(128, 96, seed=2)
    Image.fromarray(s.left).save(tmp_path / "l.png")
    Image.fromarray(s.right).save(tmp_path / "r.png")
    f, cx, cy, tx = 721.5377, 60.5, 45.25, -387.5744  # P3[0, 3] = -f * baseline
    zeros = "0.000000e+00"
    (tmp_path / "calib.txt").write_text(
        "".join(
            f"P{i}: {f} {zeros} {cx} {t} {zeros} {f} {cy} {zeros} {zeros} {zeros} 1 {zeros}\n"
            for i, t in ((0, 0.0), (1, tx), (2, 0.0), (3, tx))
        )
    )
    code, text, err = run(
        capsys,
        tmp_path / "l.png",
        tmp_path / "r.png",
        "--calib",
        tmp_path / "calib.txt",
        "-o",
        tmp_path / "k-",
        "--ply",
        "--json",
        "--no-preview",
    )
    assert code == 0, err
    d = read_disparity_pfm(tmp_path / "k-disparity.pfm")
    baseline_m = -tx / f
    depth = disparity_to_depth(d, focal_px=f, baseline_m=baseline_m)
    assert same(np.load(tmp_path / "k-depth.npy"), depth)
    points = reproject(d, focal_px=f, baseline_m=baseline_m, cx_px=cx, cy_px=cy)
    ok = np.isfinite(points).all(axis=-1)
    data = (tmp_path / "k-points.ply").read_bytes()
    assert f"element vertex {int(ok.sum())}\n".encode() in data[:300]
    body = data[data.index(b"end_header\n") + len(b"end_header\n") :]
    vertex = np.frombuffer(body, dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    assert np.array_equal(vertex["xyz"], points[ok])  # the calibration's cx, cy
    assert np.array_equal(vertex["rgb"], s.left[ok])
    rig = json.loads(text)["rig"]
    assert rig == {"focal_px": f, "baseline_m": baseline_m, "doffs_px": 0.0}


@pytest.mark.parametrize(
    ("folders", "baseline_m"),
    [(("image_0", "image_1"), 0.1), (("image_2", "image_3"), 0.11), (("a", "b"), 0.11)],
)
def test_kitti_calib_cameras_follow_the_folders(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], folders: tuple[str, str], baseline_m: float
) -> None:
    """A KITTI file has four cameras: the grey pair image_0/image_1 (KITTI odometry's grey
    set, with its calib.txt) has another baseline than the colour pair image_2/image_3, which
    it once got; other folders keep the colour pair, the default."""
    s = sample_pair(96, 64, seed=3)
    left, right = tmp_path / folders[0] / "000000.png", tmp_path / folders[1] / "000000.png"
    for path, image in ((left, s.left), (right, s.right)):
        path.parent.mkdir()
        Image.fromarray(image).save(path)
    # made-up rig: P1 70 mm right of P0, P2 60 mm left of it, P3 50 mm right
    rows = ((0, 0.0), (1, -70.0), (2, 42.0), (3, -35.0))
    (tmp_path / "calib.txt").write_text(
        "".join(f"P{i}: 700 0 48 {t} 0 700 32 0 0 0 1 0\n" for i, t in rows)
    )
    args = ("--calib", tmp_path / "calib.txt", "-o", tmp_path / "k-", "--json", "--no-preview")
    code, text, err = run(capsys, left, right, *args)
    assert code == 0, err
    assert json.loads(text)["rig"]["baseline_m"] == pytest.approx(baseline_m, rel=1e-12)


def test_kitti_grey_cameras_from_inside_the_left_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # Run from inside image_0 with LEFT given as "000000.png": its folder was "" (the
    # relative path's parent), so the colour pair's baseline was used for the grey pair.
    s = sample_pair(96, 64, seed=3)
    for folder, image in (("image_0", s.left), ("image_1", s.right)):
        (tmp_path / folder).mkdir()
        Image.fromarray(image).save(tmp_path / folder / "000000.png")
    rows = ((0, 0.0), (1, -70.0), (2, 42.0), (3, -35.0))  # grey pair 0.1 m, colour 0.11 m
    (tmp_path / "calib.txt").write_text(
        "".join(f"P{i}: 700 0 48 {t} 0 700 32 0 0 0 1 0\n" for i, t in rows)
    )
    monkeypatch.chdir(tmp_path / "image_0")
    args = ("--calib", "../calib.txt", "-o", tmp_path / "k-", "--json", "--no-preview")
    code, text, err = run(capsys, "000000.png", "../image_1/000000.png", *args)
    assert code == 0, err
    assert json.loads(text)["rig"]["baseline_m"] == pytest.approx(0.1, rel=1e-12)


# --- bad input: one line, exit 2 ------------------------------------------------------------------
@pytest.fixture
def pair(tmp_path: Path) -> tuple[Path, Path]:
    s = sample_pair(96, 64)
    Image.fromarray(s.left).save(tmp_path / "l.png")
    Image.fromarray(s.right).save(tmp_path / "r.png")
    return tmp_path / "l.png", tmp_path / "r.png"


def bad_cases(tmp: Path, left: Path, right: Path) -> list[tuple[list[Any], str]]:
    (tmp / "notimage.png").write_bytes(b"hello, not a PNG")
    Image.fromarray(np.zeros((64, 90, 3), np.uint8)).save(tmp / "small.png")
    (tmp / "bad_calib.txt").write_text("cam0=[1 0 0; 0 1 0]\nbaseline=100\n")
    wide_ndisp = write_middlebury_calib(tmp / "wide.txt", 96, 64)
    wide_ndisp.write_text(wide_ndisp.read_text().replace("ndisp=73", "ndisp=5000"))
    absurd = tmp / "absurd.txt"  # 1e30 px times 1e20 mm
    absurd.write_text(
        "cam0=[1e30 0 48; 0 1e30 32; 0 0 1]\ncam1=[1e30 0 48; 0 1e30 32; 0 0 1]\n"
        "doffs=0\nbaseline=1e20\nwidth=96\nheight=64\nndisp=16\n"
    )
    return [
        ([tmp / "nope.png", right], "LEFT: image not found"),
        (
            [left, right, "--num-disparities", "272", "--disparity-format", "png16"],
            "--disparity-format png16 holds disparities up to 255.996 px, and the search "
            "reaches 271 px",
        ),
        (
            [left, right, "--min-disparity", "-8", "--disparity-format", "png16"],
            "--disparity-format png16 holds no negative disparities (KITTI's d x 256, 0 for "
            "none), and --min-disparity -8 searches them",
        ),
        ([tmp, right], "LEFT: image is a folder, not a file"),
        (
            [left, right, "--calib", write_middlebury_calib(tmp / "big.txt", 192, 128)],
            "LEFT and RIGHT must have the size of the calibration in --calib, 192x128 px, got "
            "96x64 px",
        ),
        ([left, tmp / "notimage.png"], "RIGHT: cannot decode image"),
        ([left, tmp / "small.png"], "LEFT and RIGHT must have the same size, got 96x64 and 90x64"),
        ([left, right, "--calib", tmp / "none.txt"], "--calib: calibration file not found"),
        ([left, right, "--calib", tmp / "bad_calib.txt"], "cam0 must be a 3x3 matrix"),
        ([left, right, "--calib", tmp / "bad_calib.txt", "--focal-px", "700"], "not both"),
        ([left, right, "--focal-px", "700"], "--baseline-mm is required with --focal-px"),
        # a flag given as 0 is given: alone it was an IndexError (a traceback, exit 1), and
        # beside --calib it was ignored without a word
        ([left, right, "--focal-px", "0"], "--baseline-mm is required with --focal-px"),
        ([left, right, "--baseline-mm", "0"], "--focal-px is required with --baseline-mm"),
        ([left, right, "--calib", wide_ndisp, "--baseline-mm", "0"], "not both"),
        ([left, right, "--focal-px", "-7", "--baseline-mm", "100"], "--focal-px must be a finite"),
        ([left, right, "--doffs-px", "3"], "--doffs-px goes with --focal-px"),
        (
            [left, right, "--num-disparities", "0"],
            "num_disparities must be an integer in [1, 4096]",
        ),
        ([left, right, "--block-size", "4"], "block_size must be an odd integer"),
        # a range no pixel of the 96 px wide pair can match: the map was NaN everywhere
        (
            [left, right, "--min-disparity", "96"],
            "min_disparity=96 with num_disparities=16 searches disparities 96 to 111, none of "
            "which lies inside an image 96 pixels wide",
        ),
        ([left, right, "--cmap", "nope"], "--cmap nope: cmap must be a matplotlib colour map"),
        ([left, right, "--ply"], "--ply needs a rig"),
        ([left, right, "-o", tmp / "missing" / "p-"], "the folder of the prefix"),
        # a prefix naming a file (or /dev/null): it wrote l.pngdisparity.pfm beside it
        ([left, right, "-o", left], f"--out {left}: an existing file, not a folder"),
        ([left, right, "--threads", "-1"], "--threads must be an integer >= 0 and <= 2147483647"),
        (
            [left, right, "--threads", "2147483648"],
            # the words of batch and eval (the range's 0 said nothing of what it means)
            "--threads must be an integer >= 0 and <= 2147483647 (0: every core), got 2147483648",
        ),
        # the same file twice: every disparity 0, every depth unknown (batch's CSV refuses it)
        ([left, left], "LEFT and RIGHT are the same file"),
        ([left, tmp / ".." / tmp.name / left.name], "LEFT and RIGHT are the same file"),
        # a rig whose depths float32 cannot hold: the message named focal_px * baseline_m and
        # suggested float64 disparity, which a command-line user cannot give
        (
            [left, right, "--focal-px", "1e30", "--baseline-mm", "1e30"],
            "--focal-px 1e+30 times --baseline-mm 1e+30 is 1e+57 px*m, outside the range "
            "float32 depth maps can be computed from ([1.175e-38, 3.403e+38] px*m)",
        ),
        (
            [left, right, "--focal-px", "700", "--baseline-mm", "100", "--doffs-px", "-1e39"],
            "--doffs-px -1e+39 px is outside float32's range (|doffs| <= 3.403e+38)",
        ),
        (
            [left, right, "--calib", absurd],
            f"--calib {absurd}: focal length 1e+30 px times baseline 1e+17 m is 1e+47 px*m",
        ),
        (  # a calib.txt's ndisp out of range was blamed on --min-disparity 0, never given
            [left, right, "--calib", wide_ndisp],
            f"--calib {wide_ndisp}: its ndisp=5000 is no search range for --method bm "
            "(num_disparities must be an integer in [1, 4096], got 5000): give --num-disparities",
        ),
    ]


def test_bad_input_one_line_exit_2(
    tmp_path: Path, pair: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    for args, message in bad_cases(tmp_path, *pair):
        code, out, err = run(capsys, *args)
        assert code == 2, (args, err)
        assert out == ""
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("stereodepth match: error: "), err
        assert message in lines[0], (message, err)
        assert "Traceback" not in err
    assert not list(Path.cwd().glob("disparity*"))  # nothing written for a bad command


def test_sgm_path_with_a_stand_in_matcher(
    pair: tuple[Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The options reach semi_global_match where it takes them, its (disparity, confidence) is
    used as the block matcher's; an option it lacks is refused in one line."""
    calls: list[dict[str, Any]] = []

    def stand_in(
        left: Any,
        right: Any,
        *,
        num_disparities: int,
        min_disparity: int = 0,
        block_size: int = 5,
        threads: int | None = None,
        return_confidence: bool = False,
    ) -> Any:
        calls.append(
            {
                "num_disparities": num_disparities,
                "min_disparity": min_disparity,
                "block_size": block_size,
                "threads": threads,
                "return_confidence": return_confidence,
            }
        )
        d = block_match(left, right, num_disparities=num_disparities, block_size=block_size)
        return d, np.ones_like(d)

    monkeypatch.setattr(stereodepth, "semi_global_match", stand_in, raising=False)
    code, out, err = run(
        capsys,
        *pair,
        "--method",
        "sgm",
        "--block-size",
        "3",
        "--num-disparities",
        "32",
        "--threads",
        "1",
        "-o",
        f"{tmp_path}/s/",
        "--json",
        "--no-preview",
    )
    assert code == 0, err
    assert calls == [
        {
            "num_disparities": 32,
            "min_disparity": 0,
            "block_size": 3,
            "threads": 1,
            "return_confidence": True,
        }
    ]
    s = json.loads(out)
    assert s["method"] == "sgm" and s["params"] == {
        "num_disparities": 32,
        "min_disparity": 0,
        "block_size": 3,
    }
    left, right = read_image(pair[0]), read_image(pair[1])
    assert same(
        read_disparity_pfm(tmp_path / "s" / "disparity.pfm"),
        block_match(left, right, num_disparities=32, block_size=3),
    )
    code, _, err = run(capsys, *pair, "--method", "sgm", "--cost", "sad", "-o", f"{tmp_path}/t/")
    assert code == 2
    assert err.strip() == ("stereodepth match: error: --cost: --method sgm has no cost, got 'sad'")


def test_sgm_summary_names_the_block_size(
    pair: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The text and JSON summaries of --method sgm name the block size matched with, given
    or the matcher's default, as they do for bm."""
    if not sgm_available():
        pytest.skip("this version of the library has no semi_global_match")
    from stereodepth.semi_global import DEFAULT_BLOCK_SIZE

    argv = ["--method", "sgm", "--num-disparities", "32", "--no-preview"]
    code, out, err = run(capsys, *pair, *argv, "-o", f"{tmp_path}/a/", "--json")
    assert code == 0, err
    assert json.loads(out)["params"]["block_size"] == DEFAULT_BLOCK_SIZE
    code, out, err = run(capsys, *pair, *argv, "--block-size", "1", "-o", f"{tmp_path}/b/")
    assert code == 0, err
    assert "matcher    sgm, block 1, disparities 0 to 31 px (32)" in out.splitlines()


def test_sgm_without_the_semi_global_matcher(
    pair: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    if sgm_available():
        code, _, err = run(capsys, *pair, "--method", "sgm", "-o", f"{tmp_path / 'sgm'}/")
        assert code == 0, err
        assert (tmp_path / "sgm" / "disparity.pfm").is_file()
        return
    code, _, err = run(capsys, *pair, "--method", "sgm", "-o", f"{tmp_path / 'sgm'}/")
    assert code == 2
    assert err.strip() == (
        "stereodepth match: error: method 'sgm' needs stereodepth.semi_global_match, which this "
        "version of the library does not have; use method 'bm'"
    )
    assert not hasattr(stereodepth, "semi_global_match")


def test_a_failed_write_leaves_no_outputs(
    pair: tuple[Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """An output name taken by a folder is refused before any work; a write that fails after
    others leaves none of the run's outputs (the disparity and depth used to stay, without a
    cloud), and an earlier run's file of the same name as it was (it used to be removed)."""
    out = tmp_path / "out"
    (out / "points.ply").mkdir(parents=True)
    rig = ["--focal-px", "100", "--baseline-mm", "100", "--no-preview", "--ply"]
    code, _, err = run(capsys, *pair, *rig, "-o", f"{out}/")
    assert code == 2 and err.count("\n") == 1
    assert "points.ply' is a folder, so the output of that name cannot be written" in err
    assert sorted(p.name for p in out.iterdir()) == ["points.ply"]

    import stereodepth.pointcloud

    def disk_full(*args: Any, **kwargs: Any) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(stereodepth.pointcloud, "write_ply", disk_full)
    (out / "points.ply").rmdir()
    (out / "depth.npy").write_bytes(b"an earlier run's depth")  # (replacing it takes --force)
    code, _, err = run(capsys, *pair, *rig, "--force", "-o", f"{out}/")
    assert code == 1 and "No space left on device" in err and err.count("\n") == 1
    assert list(out.iterdir()) == [out / "depth.npy"]
    assert (out / "depth.npy").read_bytes() == b"an earlier run's depth"


def test_ply_of_a_12_bit_pair_is_coloured_as_matched(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A Mono12 camera's pair (0..4095 in uint16): the points used to take the high byte of
    # the left image, 0..15, a black cloud; they now take its min-max stretch, the matcher's.
    from stereodepth.colormap import to_uint8
    from stereodepth.io import write_png16

    s = sample_pair(96, 72, seed=9)
    grey = s.left if s.left.ndim == 2 else s.left.mean(axis=-1).astype(np.uint8)
    grey_r = s.right if s.right.ndim == 2 else s.right.mean(axis=-1).astype(np.uint8)
    left16, right16 = grey.astype(np.uint16) * 16, grey_r.astype(np.uint16) * 16
    write_png16(tmp_path / "l.png", left16)
    write_png16(tmp_path / "r.png", right16)
    rig = ["--focal-px", "100", "--baseline-mm", "100", "--no-preview", "--ply"]
    code, _, err = run(capsys, tmp_path / "l.png", tmp_path / "r.png", *rig, "-o", tmp_path / "m-")
    assert code == 0, err
    d = read_disparity_pfm(tmp_path / "m-disparity.pfm")
    ok = np.isfinite(reproject(d, focal_px=100.0, baseline_m=0.1)).all(axis=-1)
    data = (tmp_path / "m-points.ply").read_bytes()
    body = data[data.index(b"end_header\n") + len(b"end_header\n") :]
    vertex = np.frombuffer(body, dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    colours = to_uint8(left16)[ok]
    assert np.array_equal(vertex["rgb"], np.repeat(colours[:, None], 3, axis=1))
    assert colours.max() > 200  # not the high byte (at most 15)


def test_a_refused_pair_leaves_no_new_out_folder(
    tmp_path: Path, pair: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """--out's new folders were made before the pair was matched, and stayed, empty, when
    the pair was refused (here a grey right image beside a colour left one)."""
    left, _ = pair
    Image.open(left).convert("L").save(tmp_path / "copy.png")
    out = tmp_path / "new" / "deeper"
    before = sorted(p.name for p in tmp_path.iterdir())
    code, _, err = run(capsys, left, tmp_path / "copy.png", "-o", f"{out}/")
    assert code == 2, err
    assert "right must be colour (RGB) as left is" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    # an existing folder stays, as it was
    out.mkdir(parents=True)
    code, _, err = run(capsys, left, tmp_path / "copy.png", "-o", f"{out}/")
    assert code == 2 and out.is_dir() and list(out.iterdir()) == []


def help_text(capsys: pytest.CaptureFixture[str], command: str) -> str:
    """``stereodepth COMMAND --help``'s text, its white space collapsed."""
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    return " ".join(capsys.readouterr().out.split())


def test_help_gives_each_methods_block_sizes(capsys: pytest.CaptureFixture[str]) -> None:
    # --block-size said "(odd)", yet --method sgm takes 1 or 3 only (and bm 3 to 63 / 31).
    text = help_text(capsys, "match")
    block = text.split("--block-size N ")[1].split(" --cost {census,sad}")[0]
    assert "sgm 1 or 3 only" in block
    assert "3 to 63 with --cost census, 3 to 31 with --cost sad" in block
    assert "(odd)" not in block
    assert "1 to 4096 with either method" in text
    assert "an integer from -32768 to 32768, either method" in text  # it said "any integer"
    assert "--method bm only" in text.split("--cost {census,sad} ")[1]


def test_batch_help_gives_each_methods_block_sizes(capsys: pytest.CaptureFixture[str]) -> None:
    # The same for batch, which said "bm: odd, >= 3" without the upper limits.
    text = help_text(capsys, "batch")
    block = text.split("--block-size N ")[1].split(" --cost {census,sad}")[0]
    assert "bm an odd number, 3 to 63 with --cost census, 3 to 31 with --cost sad" in block
    assert "sgm 1 or 3 only" in block


def test_a_read_only_output_is_refused_before_matching(
    tmp_path: Path, pair: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # An earlier run's disparity.pfm made read-only: a usage error naming --out before the
    # pair is matched (it was exit 1 with the OS's "[Errno 13]" after the match), and the file
    # is kept as it was.
    out = tmp_path / "out"
    code, _, err = run(capsys, *map(str, pair), "-o", f"{out}/", "--num-disparities", "16")
    assert code == 0, err
    kept = out / "disparity.pfm"
    before = kept.read_bytes()
    kept.chmod(0o444)
    try:
        code, text, err = run(capsys, *map(str, pair), "-o", f"{out}/", "--num-disparities", "32")
    finally:
        kept.chmod(0o644)
    assert code == 2, err
    assert text == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"stereodepth match: error: --out {out}/: cannot write ")
    assert "disparity.pfm: the file is read-only" in lines[0]
    assert "Errno" not in lines[0]
    assert kept.read_bytes() == before
