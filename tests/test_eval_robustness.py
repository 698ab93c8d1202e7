"""``stereodepth eval`` on damaged or unusual inputs: .npy files whose size disagrees with
their header; OpenCV's error messages kept whole, on one line."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stereodepth
from stereodepth import cli

PIL_Image = pytest.importorskip("PIL.Image")


def textured_pair(height: int, width: int, shift: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random grey texture, the right image the left one moved ``shift`` px to the left."""
    rng = np.random.default_rng(seed)
    texture = rng.integers(0, 256, (height, width + shift), dtype=np.uint8)
    return np.ascontiguousarray(texture[:, :width]), np.ascontiguousarray(texture[:, shift:])


def write_scene(folder: Path, left: np.ndarray, right: np.ndarray, disparity: float) -> Path:
    """Our layout: left.png, right.png (16-bit when the arrays are uint16), disp_gt.npy
    (``disparity`` everywhere) and mask_nonocc.npy (all true)."""
    folder.mkdir(parents=True)
    for name, image in (("left.png", left), ("right.png", right)):
        if image.dtype == np.uint16:
            stereodepth.io.write_png16(folder / name, image)
        else:
            PIL_Image.fromarray(image).save(folder / name)
    np.save(folder / "disp_gt.npy", np.full(left.shape[:2], disparity, np.float32))
    np.save(folder / "mask_nonocc.npy", np.ones(left.shape[:2], bool))
    return folder


def run_eval(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = cli.main(["eval", *argv])
    out, err = capsys.readouterr()
    return status, out, err


@pytest.fixture
def scene(tmp_path: Path) -> Path:
    left, right = textured_pair(64, 128, 5, seed=1)
    return write_scene(tmp_path / "scenes" / "s1", left, right, 5.0)


# --------------------------------------------------------------------------------------------
# .npy files whose size disagrees with their header


def damaged(content: bytes, fault: str) -> bytes:
    """A copy of the .npy file ``content`` (version 1.0, shape (64, 128)) with ``fault``."""
    from numpy.lib import format as npy

    header_end = content.index(b"\n") + 1
    if fault == "truncated":
        return content[:-100]
    if fault == "padded":
        return content + b"\0" * 100
    if fault == "header only":
        return content[:header_end]
    if fault == "huge shape":  # numpy allocated it: MemoryError
        buffer = io.BytesIO()
        dtype = np.load(io.BytesIO(content)).dtype
        header = {"descr": npy.dtype_to_descr(dtype), "fortran_order": False}
        npy.write_array_header_1_0(buffer, {**header, "shape": (10**6, 10**6)})
        return buffer.getvalue() + content[header_end:]
    assert fault == "damaged header"  # numpy raised tokenize's TokenError
    bad = content.replace(b"(64, 128), }", b"(64, 128 , }")
    assert bad != content and len(bad) == len(content)
    return bad


NPY_FAULTS = [
    ("truncated", "truncated: its header gives {dtype} (64, 128), {size} bytes of data, but "
     "the file holds {short} bytes after its 128-byte header"),
    ("padded", "followed by 100 stray byte(s): its header gives {dtype} (64, 128), {size} bytes "
     "of data, but the file holds {long} bytes"),
    ("header only", "truncated: its header gives {dtype} (64, 128), {size} bytes of data, but "
     "the file holds 0 bytes"),
    ("huge shape", "truncated: its header gives {dtype} (1000000, 1000000)"),
    ("damaged header", "not a readable .npy array (its header: "),
]  # fmt: skip


@pytest.mark.parametrize("name", ["disp_gt.npy", "mask_nonocc.npy"])
@pytest.mark.parametrize(("fault", "fragment"), NPY_FAULTS)
def test_npy_whose_size_disagrees_with_its_header_is_refused(
    scene: Path, capsys: pytest.CaptureFixture[str], name: str, fault: str, fragment: str
) -> None:
    """A padded .npy was read without a word, a damaged header raised TokenError and a
    damaged shape MemoryError (tracebacks), a truncated one gave numpy's words naming no
    size: one line naming the file, what its header gives and what the file holds."""
    path = scene / name
    content = path.read_bytes()
    dtype = np.load(path).dtype
    size = 64 * 128 * dtype.itemsize
    assert len(content) == 128 + size  # the header's length the fragments name
    path.write_bytes(damaged(content, fault))
    status, out, err = run_eval(capsys, str(scene), "--repeat", "1")
    assert status == 2 and out == "", err
    assert err.startswith("stereodepth eval: error: ") and err.count("\n") == 1, err
    want = fragment.format(dtype=dtype, size=size, short=size - 100, long=size + 100)
    assert f"{path}: " in err and want in err, err


def test_npy_of_the_right_size_is_read(scene: Path) -> None:
    """The check reads the header as numpy does: both format versions, either byte order."""
    from stereodepth.evaluation import _load_npy

    want = np.arange(64 * 128, dtype=">f8").reshape(64, 128)
    for version in ((1, 0), (2, 0)):
        path = scene / f"v{version[0]}.npy"
        with open(path, "wb") as f:
            np.lib.format.write_array(f, want, version=version)
        got = _load_npy(path)
        assert got.dtype == want.dtype and np.array_equal(got, want)
        with open(path, "ab") as f:
            f.write(b"\0")
        with pytest.raises(ValueError, match="followed by 1 stray byte"):
            _load_npy(path)


# --------------------------------------------------------------------------------------------
# OpenCV's errors


def opencv_error(call: Any) -> Any:
    """The cv2.error that ``call()`` raises (skips when this OpenCV does not raise)."""
    cv2 = pytest.importorskip("cv2")
    try:
        call()
    except cv2.error as exc:
        return exc
    pytest.skip("this OpenCV does not raise here")


def test_opencv_error_keeps_its_explanation_on_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """SGBM's error for images too narrow for the search range says why on its second line
    and gives the values on the next ones: only the last ("'...width/2' is 2") was kept."""
    cv2 = pytest.importorskip("cv2")
    left, right = textured_pair(32, 34, 5, seed=2)  # 34 - 32 disparities <= block size 5 // 2
    folder = write_scene(tmp_path / "narrow", left, right, 5.0)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=32, blockSize=5, P1=200, P2=800)
    exc = opencv_error(lambda: sgbm.compute(left, right))
    explanation = [line.lstrip(">").strip() for line in exc.err.strip().splitlines()]
    assert len(explanation) > 1  # the case: several lines
    status, out, err = run_eval(
        capsys, str(folder), "--method", "opencv-sgbm", "--num-disparities", "32", "--repeat", "1"
    )
    assert status == 2 and out == ""  # refused on the only scene: nothing scored
    assert err.startswith(
        "stereodepth eval: error: nothing was scored: no method ran on the scene: "
        "scene narrow: opencv-sgbm (block 5): OpenCV refused the images: ("
    )
    assert err.count("\n") == 1 and err.count("opencv-sgbm") == 1, err
    for text in explanation:
        assert text and text in err, (text, err)
    assert f"({exc.code}:" in err and f"in function '{exc.func}'" in err
    assert exc.file not in err  # the source location left out


def test_opencv_message_forms() -> None:
    """One line each: the code, kind, check and function of a one-line error, without
    OpenCV's version and source file; the bindings' lines below it after ": "."""
    from stereodepth.evaluation import _cv_message

    cv2 = pytest.importorskip("cv2")
    grey16 = np.zeros((40, 60), np.uint16)
    exc = opencv_error(lambda: cv2.StereoBM_create(16, 9).compute(grey16, grey16))
    message = _cv_message(exc)
    assert "\n" not in message and exc.err.strip() in message
    assert message.startswith(f"({exc.code}:") and message.endswith(f"in function '{exc.func}'")
    assert exc.file not in message and not message.startswith("OpenCV")
    grey = np.zeros((40, 60), np.uint8)
    exc = opencv_error(lambda: cv2.StereoBM_create(16, 9).compute("left", grey))
    message = _cv_message(exc)
    assert "\n" not in message and message.startswith(f"({exc.code}:")
    for line in exc.err.strip().splitlines():
        assert line.lstrip(">").strip() in message
    assert _cv_message(ValueError("")) == "ValueError"
    assert _cv_message(ValueError(" one\n two ")) == "one: two"


# --------------------------------------------------------------------------------------------
# Scenes OpenCV's matchers do not take: 16-bit images


@pytest.fixture
def mixed_depths(tmp_path: Path) -> Path:
    """Three scenes, the middle one (b16) 16-bit: the same texture as a, scaled by 257."""
    root = tmp_path / "scenes"
    for name, seed in (("a", 1), ("b16", 1), ("c", 2)):
        left, right = textured_pair(48, 96, 6, seed=seed)
        if name == "b16":
            left, right = (image.astype(np.uint16) * 257 for image in (left, right))
        write_scene(root / name, left, right, 6.0)
    return root


def by_variant(entries: list[dict[str, Any]]) -> dict[tuple[str, Any, bool], dict[str, Any]]:
    return {(e["method"], e["block_size"], e.get("best", False)): e for e in entries}


def test_a_16_bit_scene_is_not_applicable_to_opencv_and_scored_for_the_others(
    mixed_depths: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One 16-bit scene ended the whole run (exit status 2) when an OpenCV method was asked
    for: now OpenCV's rows there are n/a with the reason, every other method and scene is
    scored, and each mean says how many scenes it is over."""
    pytest.importorskip("cv2")
    status, out, err = run_eval(
        capsys, str(mixed_depths), "--method", "stereodepth", "opencv-bm:9,15", "opencv-sgbm",
        "--repeat", "1", "--json",
    )  # fmt: skip
    assert status == 0, err
    report = json.loads(out)
    assert report["scenes"] == ["a", "b16", "c"]
    scored = [(r["scene"], r["method"], r["block_size"], r["best"]) for r in report["results"]]
    opencv = [("opencv-bm", 9, False), ("opencv-bm", 15, False)]
    opencv += [("opencv-bm", None, True), ("opencv-sgbm", 5, False)]
    assert [s[0] for s in scored if s[1] == "stereodepth"] == ["a", "b16", "c"]
    assert {(m, b) for _, m, b, best in scored if m != "stereodepth" and not best} == {
        (m, b) for m, b, best in opencv if not best
    }
    assert {s[0] for s in scored if s[1] != "stereodepth"} == {"a", "c"}
    na = report["not_applicable"]
    assert [(x["scene"], x["method"], x["block_size"]) for x in na] == [
        ("b16", "opencv-bm", 9),
        ("b16", "opencv-bm", 15),
        ("b16", "opencv-sgbm", 5),
    ]
    for x in na:
        assert "8-bit images only" in x["reason"] and "uint16" in x["reason"], x
    # 16-bit fed to our matcher as it is: b16 is a's texture, scaled
    (ours_a,) = [r for r in report["results"] if r["scene"] == "a" and r["method"] == "stereodepth"]
    (ours_b,) = [r for r in report["results"] if r["scene"] == "b16"]
    assert ours_b["metrics"]["density"] > 0.5 and ours_b["metrics"]["bad_2_est"] < 0.05
    assert ours_a["metrics"]["density"] > 0.5
    means = by_variant(report["means"])
    (ours,) = [m for m in report["means"] if m["method"] == "stereodepth"]
    assert ours["scenes"] == 3 and ours["scenes_not_applicable"] == []
    for method, block, best in opencv:
        mean = means[(method, block, best)]
        assert mean["scenes"] == 2 and mean["scenes_not_applicable"] == ["b16"], mean
        rows = [
            r
            for r in report["results"]
            if r["method"] == method and r["best"] == best and (best or r["block_size"] == block)
        ]
        assert [r["scene"] for r in rows] == ["a", "c"]
        for key in ("bad_2", "density", "avgerr"):
            want = sum(r["metrics"][key] for r in rows) / 2
            assert mean["metrics"][key] == pytest.approx(want, rel=1e-12), key
    assert {t["scenes"] for t in report["time_ratios"]} == {2}
    (note,) = report["notes"]
    assert note.startswith("opencv-bm, opencv-sgbm not run on 1 of 3 scene(s) (b16): ")
    assert err == f"stereodepth eval: {note}\n"


@pytest.mark.parametrize("markdown", [False, True])
def test_the_tables_mark_not_applicable_rows_and_partial_means(
    mixed_depths: Path, capsys: pytest.CaptureFixture[str], markdown: bool
) -> None:
    pytest.importorskip("cv2")
    extra = ["--markdown"] if markdown else []
    status, out, err = run_eval(
        capsys, str(mixed_depths), "--method", "bm", "opencv-sgbm", "--repeat", "1", *extra
    )
    assert status == 0, err
    if markdown:
        cells = [[c.strip() for c in line.strip("| ").split("|")] for line in out.splitlines()]
    else:
        cells = [line.split() for line in out.splitlines()]
    rows = {(c[0], c[1]): c for c in cells if len(c) > 5}
    assert [c for c in rows[("b16", "opencv-sgbm")][2:] if c] == ["5", *["n/a"] * 11]
    assert rows[("b16", "stereodepth")][3:5] == ["16", "nonocc"]
    assert all(rows[(s, m)][5] != "n/a" for s in ("a", "c") for m in ("stereodepth", "opencv-sgbm"))
    assert ("mean", "stereodepth") in rows and ("mean", "opencv-sgbm") not in rows
    if markdown:
        assert rows[("mean 2/3", "opencv-sgbm")][2] == "5"
    else:  # split on spaces: "mean" "2/3" "opencv-sgbm"
        assert any(c[:3] == ["mean", "2/3", "opencv-sgbm"] for c in cells)
    assert "n/a: opencv-sgbm not run on b16: OpenCV's StereoBM and StereoSGBM take 8-bit " in out
    assert (
        "mean 2/3: the means of opencv-sgbm are over the 2 of the 3 scenes it ran on: "
        "not comparable with means over all of them"
    ) in out
    assert "median over 2 scene(s)" in out


@pytest.mark.parametrize(
    ("method", "flag", "matcher"),
    [("sgm", "--sgm-option", "SemiGlobalMatcher"), ("bm", "--option", "StereoMatcher")],
)
def test_intensity_range_with_an_8_bit_scene_is_refused_before_any_matching(
    mixed_depths: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    method: str,
    flag: str,
    matcher: str,
) -> None:
    """intensity_range is for 16-bit images: b16 was matched, then c (8-bit) ended the run
    with exit status 2, b16's work lost. The up-front scene checks refuse it, naming the
    option as typed and the first 8-bit scene, before any matching."""
    from stereodepth import matching, semi_global

    module = semi_global if method == "sgm" else matching
    calls: list[str] = []

    class Counted(getattr(module, matcher)):  # type: ignore[misc]
        def compute(self, *args: Any, **kwargs: Any) -> Any:
            calls.append("compute")
            return super().compute(*args, **kwargs)

    monkeypatch.setattr(module, matcher, Counted)
    argv = [str(mixed_depths), "--method", method]
    status, out, err = run_eval(capsys, *argv, flag, "intensity_range=0,4095")
    assert (status, out) == (2, "")
    assert err == (
        f"stereodepth eval: error: {flag} intensity_range=0,4095: intensity_range is for "
        f"16-bit images ({'sgm' if method == 'sgm' else 'stereodepth'} matches 8-bit ones as "
        "they are), and scene a is 8-bit: leave the option out, or that scene (--scene)\n"
    )
    status, out, err = run_eval(
        capsys, *argv, flag, "intensity_range=0,4095", "--scene", "b16", "--scene", "c"
    )
    assert (status, out) == (2, "") and "and scene c is 8-bit" in err, err
    assert calls == []
    status, out, err = run_eval(
        capsys, *argv, flag, "intensity_range=0,65535", "--scene", "b16", "--repeat", "1"
    )
    assert status == 0, err
    assert calls


def test_a_method_not_applicable_on_every_scene_has_no_means(
    mixed_depths: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("cv2")
    status, out, err = run_eval(
        capsys, str(mixed_depths), "--scene", "b16", "--method", "bm", "opencv-bm", "--repeat", "1"
    )
    assert status == 0, err
    assert "mean 0/1  opencv-bm    9" in out and out.count("n/a") == 2 * 11 + 1, out
    assert "mean 0/1: opencv-bm did not run on the scene: no means" in out  # not "1 scenes"
    # not "the means of opencv-bm are over the other 0 scene(s)"
    assert err.endswith("; those rows are n/a, and opencv-bm has no means\n"), err
    report = json.loads(
        run_eval(
            capsys, str(mixed_depths), "--scene", "b16", "--method", "bm", "opencv-bm",
            "--repeat", "1", "--json",
        )[1]
    )  # fmt: skip
    mean = by_variant(report["means"])[("opencv-bm", 9, False)]
    assert mean["scenes"] == 0 and mean["scenes_not_applicable"] == ["b16"]
    assert set(mean["metrics"].values()) == {None} and mean["time_s"] is None


def test_nothing_to_evaluate_is_an_error_before_any_matching(
    mixed_depths: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Only OpenCV methods, and no 8-bit scene: nothing would be scored."""
    import stereodepth.evaluation as evaluation

    pytest.importorskip("cv2")
    calls: list[str] = []
    monkeypatch.setattr(evaluation, "_timed", lambda *a, **k: calls.append("matched"))
    (mixed_depths / "zz16").mkdir()
    for name in ("left.png", "right.png", "disp_gt.npy"):
        (mixed_depths / "zz16" / name).write_bytes((mixed_depths / "b16" / name).read_bytes())
    for scenes, where in ((["b16"], "scene b16"), (["*16"], "any of the 2 scenes (b16, zz16)")):
        patterns = [a for s in scenes for a in ("--scene", s)]
        status, out, err = run_eval(
            capsys, str(mixed_depths), *patterns, "--method", "opencv-bm", "opencv-sgbm"
        )
        assert status == 2 and out == ""
        assert err == (
            f"stereodepth eval: error: nothing to evaluate: opencv-bm, opencv-sgbm cannot run "
            f"on {where}: OpenCV's StereoBM and StereoSGBM take 8-bit images only, got uint16 "
            "(stereodepth and sgm take 16-bit images: --method stereodepth sgm)\n"
        )
    assert calls == []


# --------------------------------------------------------------------------------------------
# Scenes an OpenCV matcher refuses: images too small for its block size and range


@pytest.fixture
def with_tiny(tmp_path: Path) -> Path:
    """Two 8-bit scenes: big (48 x 96 px) and tiny (12 x 20 px, too narrow for SGBM with
    block size 31 and 16 disparities: 20 - 16 > 31 // 2 fails)."""
    root = tmp_path / "scenes"
    write_scene(root / "big", *textured_pair(48, 96, 6, seed=1), 6.0)
    write_scene(root / "tiny", *textured_pair(12, 20, 3, seed=3), 3.0)
    return root


def test_a_scene_opencv_refuses_is_not_applicable_to_that_method(
    with_tiny: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """OpenCV refusing one scene's images (a cv2.error from compute) ended the whole run
    (exit status 2, no table): now that row is n/a with OpenCV's explanation, as on a 16-bit
    scene, and every other row is scored."""
    cv2 = pytest.importorskip("cv2")
    left, right = textured_pair(12, 20, 3, seed=3)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=16, blockSize=31)
    exc = opencv_error(lambda: sgbm.compute(left, right))
    argv = [str(with_tiny), "--method", "stereodepth", "opencv-sgbm:5,31", "--repeat", "1"]
    status, out, err = run_eval(capsys, *argv, "--json")
    assert status == 0, err
    report = json.loads(out)
    scored = [(r["scene"], r["method"], r["block_size"], r["best"]) for r in report["results"]]
    assert scored == [
        ("big", "stereodepth", 9, False),
        ("big", "opencv-sgbm", 5, False),
        ("big", "opencv-sgbm", 31, False),
        ("big", "opencv-sgbm", r_best(report, "big"), True),
        ("tiny", "stereodepth", 9, False),
        ("tiny", "opencv-sgbm", 5, False),  # no best= row: block 31 did not run there
    ]
    (na,) = report["not_applicable"]
    assert (na["scene"], na["method"], na["block_size"]) == ("tiny", "opencv-sgbm", 31)
    assert na["reason"].startswith("OpenCV refused the images: (")
    assert "too small for your window size and max disparity" in na["reason"]
    assert exc.err.strip().splitlines()[0].lstrip(">").strip() in na["reason"]
    means = by_variant(report["means"])
    assert means[("stereodepth", 9, False)]["scenes"] == 2
    assert means[("opencv-sgbm", 5, False)]["scenes"] == 2
    for key in (("opencv-sgbm", 31, False), ("opencv-sgbm", None, True)):
        assert means[key]["scenes"] == 1 and means[key]["scenes_not_applicable"] == ["tiny"]
    (note,) = report["notes"]
    assert note.startswith(
        "opencv-sgbm (block 31) not run on 1 of 2 scene(s) (tiny): OpenCV refused the images: ("
    )
    assert note.endswith(
        "; those rows are n/a, and the means of opencv-sgbm (block 31) are over the other 1 scene"
    )
    assert err == f"stereodepth eval: {note}\n"
    # the tables: an n/a row, mean 1/2 and the reason under the table
    status, out, err = run_eval(capsys, *argv)
    assert status == 0 and err == f"stereodepth eval: {note}\n"
    rows = [line.split() for line in out.splitlines()]
    assert ["tiny", "opencv-sgbm", "31", *["n/a"] * 11] in rows
    assert any(r[:4] == ["mean", "1/2", "opencv-sgbm", "31"] for r in rows), out
    assert any(r[:4] == ["mean", "1/2", "opencv-sgbm", "best"] for r in rows), out
    # block 5 was scored on tiny: the lines under the table name block 31
    assert "n/a: opencv-sgbm:31 not run on tiny: OpenCV refused the images: (" in out
    assert "opencv-sgbm not run" not in out
    assert (
        "mean 1/2: the means of opencv-sgbm:31, opencv-sgbm:best are over the 1 of the 2 "
        "scenes each ran on: not comparable with means over all of them"
    ) in out


def test_the_lines_under_the_table_name_the_block_size(
    with_tiny: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """opencv-bm:9,15 with block 15 n/a on mid and tiny, block 9 on tiny only: the footer
    said "opencv-bm not run on ..." beside block 9's scores there, and "the means of
    opencv-bm are over ..." twice, with two counts."""
    pytest.importorskip("cv2")
    write_scene(with_tiny / "mid", *textured_pair(20, 26, 3, seed=4), 3.0)  # BM 15: empty
    status, out, err = run_eval(capsys, str(with_tiny), "--method", "opencv-bm:9,15")
    assert status == 0, err
    under = out.split("\n\n")[3].splitlines()
    assert under == [
        f"n/a: opencv-bm:15 not run on mid, tiny: {EMPTY_REGION}",
        f"n/a: opencv-bm:9 not run on tiny: {EMPTY_REGION}",
        "mean 2/3: the means of opencv-bm:9 are over the 2 of the 3 scenes it ran on: not "
        "comparable with means over all of them",
        "mean 1/3: the means of opencv-bm:15, opencv-bm:best are over the 1 of the 3 scenes "
        "each ran on: not comparable with means over all of them",
    ], out
    assert err.splitlines() == [
        f"stereodepth eval: opencv-bm (block 15) not run on 2 of 3 scene(s) (mid, tiny): "
        f"{EMPTY_REGION}; those rows are n/a, and the means of opencv-bm (block 15) are over "
        "the other 1 scene",
        f"stereodepth eval: opencv-bm (block 9) not run on 1 of 3 scene(s) (tiny): "
        f"{EMPTY_REGION}; those rows are n/a, and the means of opencv-bm (block 9) are over "
        "the other 2 scenes",
    ]
    # all the block sizes of a method n/a on the same scenes: the method named alone
    status, out, err = run_eval(capsys, str(with_tiny), "--method", "opencv-bm:9,15", "bm")
    assert status == 0, err
    assert f"n/a: opencv-bm not run on tiny: {EMPTY_REGION}" not in out
    status, out, err = run_eval(
        capsys, str(with_tiny), "--scene", "tiny", "--method", "opencv-bm:9,15", "bm"
    )
    assert status == 0, err
    assert f"n/a: opencv-bm not run on tiny: {EMPTY_REGION}" in out
    assert "mean 0/1: opencv-bm:9, opencv-bm:15 did not run on the scene: no means" in out
    # one scene: no "over the other 0 scene(s)"
    assert "other 0" not in err and err.count("opencv-bm (block 9) has no means") == 1, err


def r_best(report: dict[str, Any], scene: str) -> int:
    """The block size of the best= row of ``scene``."""
    (best,) = [r for r in report["results"] if r["scene"] == scene and r["best"]]
    block: int = best["block_size"]
    return block


def test_opencv_refusing_every_scene_is_an_error(
    with_tiny: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Nothing scored: an error, one line, naming the scene, the method (once) and why."""
    pytest.importorskip("cv2")
    status, out, err = run_eval(
        capsys, str(with_tiny), "--scene", "tiny", "--method", "opencv-sgbm:31", "opencv-bm:15"
    )
    assert (status, out) == (2, "")
    assert err.startswith(
        "stereodepth eval: error: nothing was scored: no method ran on the scene: "
        "scene tiny: opencv-sgbm (block 31): OpenCV refused the images: ("
    )
    assert err.endswith(" (and 1 more refusal(s))\n") and err.count("\n") == 1, err


class FakeMatcher:
    """An OpenCV matcher whose compute returns ``raw`` or raises ``error``."""

    def __init__(self, raw: np.ndarray | None = None, error: Exception | None = None):
        self.raw, self.error = raw, error

    def compute(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        if self.error is not None:
            raise self.error
        assert self.raw is not None and self.raw.shape == left.shape[:2]
        return self.raw.copy()


def test_an_opencv_failure_that_is_no_refusal_ends_the_run(
    scene: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Out of memory is not OpenCV refusing the scene's images: the run ends as before,
    naming the method once (it read "opencv-sgbm: opencv-sgbm failed: ...")."""
    cv2 = pytest.importorskip("cv2")
    error = cv2.error("OpenCV(5.0.0) alloc.cpp:73: error: (-4:Insufficient memory) Failed")
    error.code = cv2.Error.StsNoMem
    monkeypatch.setattr(cv2, "StereoSGBM_create", lambda **kw: FakeMatcher(error=error))
    status, out, err = run_eval(capsys, str(scene), "--method", "stereodepth", "opencv-sgbm")
    assert (status, out) == (2, "")
    assert err == (
        "stereodepth eval: error: scene s1: opencv-sgbm: OpenCV failed: (-4:Insufficient "
        "memory) Failed\n"
    )


def test_our_matchers_errors_still_end_the_run(
    scene: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from stereodepth import matching

    pytest.importorskip("cv2")

    class Failing:
        def __init__(self, **kwargs: Any) -> None:
            pass

        def compute(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
            raise ValueError("a bug to see")

    monkeypatch.setattr(matching, "StereoMatcher", Failing)
    status, out, err = run_eval(capsys, str(scene), "--method", "opencv-bm", "stereodepth")
    assert (status, out) == (2, "")
    assert err == "stereodepth eval: error: scene s1: stereodepth: a bug to see\n"


# --------------------------------------------------------------------------------------------
# OpenCV's values outside the searched range: holes, and said


def test_opencv_values_outside_the_searched_range_are_holes(
    scene: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """StereoBM on a narrow image returns uninitialised values (-31960 .. 32521 on 12 x 20
    px): those above the range were scored as disparities (avgerr 767 px, exit status 0)
    and those below silently taken as holes. All are holes now, and a note says how many."""
    cv2 = pytest.importorskip("cv2")
    raw = np.full((64, 128), 5 * 16, np.int16)  # the truth: 5 px everywhere
    raw[0, :4] = [-31960, 32521, 16 * 16, -1]  # beyond 0 .. 15 px, and not the hole -16
    raw[1, :3] = [-16, 15 * 16 + 15, 0]  # a hole, the range's ends
    monkeypatch.setattr(cv2, "StereoBM_create", lambda **kw: FakeMatcher(raw=raw))
    status, out, err = run_eval(
        capsys, str(scene), "--method", "opencv-bm", "--num-disparities", "16", "--json"
    )
    assert status == 0, err
    report = json.loads(out)
    (row,) = report["results"]
    assert row["metrics"]["density"] == pytest.approx(1 - 5 / (64 * 128))
    assert row["metrics"]["avgerr"] == pytest.approx((10.9375 + 5) / (64 * 128 - 5))
    (note,) = report["notes"]
    assert note == (
        "opencv-bm (block 9) on scene s1: OpenCV returned 4 pixels outside the searched range "
        "0 .. 15 px (raw values -31960 .. 32521, disparity x 16, OpenCV's hole being -16): not "
        "matches; scored as holes"
    )
    assert err == f"stereodepth eval: {note}\n"
    raw[0, 1:4] = 80
    status, out, err = run_eval(
        capsys, str(scene), "--method", "opencv-bm", "--num-disparities", "16"
    )
    assert status == 0, err
    assert "OpenCV returned 1 pixel outside the searched range 0 .. 15 px (raw values " in err


EMPTY_REGION = (
    "OpenCV's valid disparity region is empty for this size, window and range "
    "(cv2.getValidDisparityROI): StereoBM leaves its output unwritten"
)


def test_opencv_bm_with_an_empty_valid_region_is_not_applicable(
    with_tiny: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """StereoBM writes no pixel when its valid disparity region is empty (tiny: 20 x 12 px,
    block size 9, 16 disparities): what the memory held was scored, garbage within the
    searched range as well as outside it, different from run to run. That row is n/a now,
    the other scene's scored."""
    cv2 = pytest.importorskip("cv2")
    whole = (0, 0, 20, 12)
    assert cv2.getValidDisparityROI(whole, whole, 0, 16, 9)[2:] == (0, 0)
    argv = [str(with_tiny), "--method", "opencv-bm", "--repeat", "1"]
    status, out, err = run_eval(capsys, *argv, "--json")
    assert status == 0, err
    report = json.loads(out)
    assert [(r["scene"], r["method"]) for r in report["results"]] == [("big", "opencv-bm")]
    (na,) = report["not_applicable"]
    assert (na["scene"], na["method"], na["block_size"]) == ("tiny", "opencv-bm", 9)
    assert na["reason"] == EMPTY_REGION
    status, out, err = run_eval(capsys, *argv, "--scene", "tiny")
    assert (status, out) == (2, "")
    assert "nothing was scored" in err and "valid disparity region is empty" in err


def test_opencv_bm_writes_its_hole_value_outside_a_non_empty_valid_region() -> None:
    """Where the valid region is not empty, StereoBM writes -16 (its hole) outside it: eval
    has nothing to mask there. A pre-filled output shows what StereoBM left unwritten."""
    cv2 = pytest.importorskip("cv2")
    left, right = textured_pair(20, 30, 3, seed=2)
    whole = (0, 0, 30, 20)
    x, y, w, h = cv2.getValidDisparityROI(whole, whole, 0, 16, 9)
    assert w > 0 and h > 0
    out = cv2.StereoBM_create(numDisparities=16, blockSize=9).compute(
        left, right, np.full((20, 30), 1234, np.int16)
    )
    outside = np.ones(out.shape, bool)
    outside[y : y + h, x : x + w] = False
    assert outside.any() and (out[outside] == -16).all()


def test_opencv_sgbm_writes_every_pixel_on_a_narrow_image() -> None:
    """StereoSGBM (3-way: the mode that takes 20 x 12 px with block 9 and 16 disparities)
    has no such failure: a pre-filled output is overwritten everywhere."""
    cv2 = pytest.importorskip("cv2")
    left, right = textured_pair(12, 20, 3, seed=3)
    sgbm = cv2.StereoSGBM_create(0, 16, 9, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    out = sgbm.compute(left, right, np.full((12, 20), 1234, np.int16))
    assert not (out == 1234).any() and out.min() >= -16 and out.max() < 16 * 16


# --------------------------------------------------------------------------------------------
# A huge max_disp in meta.json


@pytest.mark.parametrize("methods", [[], ["--method", "opencv-bm"]])
def test_a_huge_max_disp_is_one_line_for_every_method(
    scene: Path, capsys: pytest.CaptureFixture[str], methods: list[str]
) -> None:
    # 1e39 printed numpy's overflow warnings before the error (the float32 ground truth
    # compared with the Python int), and with OpenCV's matchers alone it ended in a traceback
    # (an OverflowError from StereoBM_create); the number itself was printed in full.
    if methods:
        pytest.importorskip("cv2")
    (scene / "meta.json").write_text('{"max_disp": 1e39}')
    status, _, err = run_eval(capsys, str(scene.parent), *methods)
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "meta.json's max_disp=1e+39 needs 1e+39 disparities" in lines[0]
    assert "--num-disparities" in lines[0]
