"""stereodepth.io: disparity PFMs in Middlebury's convention, +inf for unknown
(write_disparity_pfm, read_disparity_pfm), and the writers that use it (batch, the web page)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import test_eval_cli

from stereodepth import io
from stereodepth.metrics import evaluate


def disparity() -> np.ndarray:
    d = np.array(
        [[1.5, np.nan, 0.0, -2.25], [np.inf, 255.5, 1e-3, np.nan], [7.0, 8.0, 300.0, 3e38]],
        np.float32,
    )
    return d


def test_holes_are_written_as_infinity_and_read_back_as_nan(tmp_path: Path) -> None:
    """Middlebury's evaldisp takes only +inf as "no value": a NaN hole was scored as a
    disparity. The holes (NaN, and +inf, Middlebury's own) are +inf on disk; every other value
    is written as write_pfm writes it, and read back as NaN and as stored."""
    d = disparity()
    hole = ~np.isfinite(d)
    for dtype in (np.float32, np.float64, ">f4"):
        io.write_disparity_pfm(tmp_path / "d.pfm", d.astype(dtype))
        raw = io.read_pfm(tmp_path / "d.pfm")
        assert np.array_equal(raw == np.inf, hole)  # evaldisp's test: d == INFINITY
        assert not np.isnan(raw).any()
        np.testing.assert_array_equal(raw[~hole], d[~hole], strict=True)
        back = io.read_disparity_pfm(tmp_path / "d.pfm")
        assert back.dtype == np.float32 and back.shape == d.shape and back.flags.writeable
        assert np.array_equal(np.isnan(back), hole)
        np.testing.assert_array_equal(back[~hole], d[~hole], strict=True)
    # The same file as write_pfm of the map with +inf holes: header, scale, layout.
    io.write_pfm(tmp_path / "ref.pfm", np.where(hole, np.inf, d))
    assert (tmp_path / "d.pfm").read_bytes() == (tmp_path / "ref.pfm").read_bytes()
    assert (tmp_path / "d.pfm").read_bytes().startswith(b"Pf\n4 3\n-1.0\n")


def test_agrees_with_the_middlebury_ground_truth_the_eval_tests_write(tmp_path: Path) -> None:
    """test_eval_cli writes a Middlebury scene's disp0GT.pfm by hand, inf where unknown, and
    evaluation reads it with read_pfm: write_disparity_pfm of the same ground truth (NaN
    holes) gives the same bytes, and read_disparity_pfm reads that file as the ground truth
    with NaN holes."""
    folder, _, _, gt = test_eval_cli.middlebury_pair(tmp_path / "scene", rgb=False)
    assert np.isnan(gt).any()
    io.write_disparity_pfm(tmp_path / "mine.pfm", gt)
    assert (tmp_path / "mine.pfm").read_bytes() == (folder / "disp0GT.pfm").read_bytes()
    np.testing.assert_array_equal(io.read_disparity_pfm(folder / "disp0GT.pfm"), gt, strict=True)
    # Scored the same, read back either way.
    est = gt + np.float32(0.3)
    io.write_disparity_pfm(tmp_path / "est.pfm", est)
    want = evaluate(est, gt)
    assert evaluate(io.read_disparity_pfm(tmp_path / "est.pfm"), gt) == want
    assert evaluate(io.read_pfm(tmp_path / "est.pfm"), io.read_pfm(folder / "disp0GT.pfm")) == want


def test_read_disparity_pfm_takes_every_non_finite_value_as_a_hole(tmp_path: Path) -> None:
    """NaN (stereodepth's disparity PFMs written with write_pfm, and match's) and -inf are
    no disparity either: NaN, as evaluate scores them. A big-endian file reads the same."""
    d = np.array([[np.nan, -np.inf, np.inf], [1.0, -0.5, 2.0]], np.float32)
    (tmp_path / "be.pfm").write_bytes(b"Pf 3 2 1\n" + d[::-1].astype(">f4").tobytes())
    io.write_pfm(tmp_path / "le.pfm", d)
    for name in ("be.pfm", "le.pfm"):
        got = io.read_disparity_pfm(tmp_path / name)
        np.testing.assert_array_equal(got, [[np.nan] * 3, [1.0, -0.5, 2.0]], strict=False)
        assert got.dtype == np.float32


def test_read_disparity_pfm_refuses(tmp_path: Path) -> None:
    io.write_pfm(tmp_path / "c.pfm", np.ones((2, 3, 3), np.float32))
    with pytest.raises(
        ValueError, match=r"c\.pfm: a disparity PFM is a grey \(Pf\) map, got a colour \(PF\) "
    ):
        io.read_disparity_pfm(tmp_path / "c.pfm")
    with pytest.raises(FileNotFoundError, match=r"PFM file not found: .*nope\.pfm"):
        io.read_disparity_pfm(tmp_path / "nope.pfm")
    (tmp_path / "t.pfm").write_bytes(b"Pf\n3 2\n-1\n" + bytes(23))
    with pytest.raises(ValueError, match=r"t\.pfm: truncated 3x2x1 PFM"):
        io.read_disparity_pfm(tmp_path / "t.pfm")


@pytest.mark.parametrize(
    ("value", "exc", "message"),
    [
        (
            np.array([[1.0, -np.inf], [-np.inf, 2.0]], np.float32),
            ValueError,
            r"^disparity must not hold -inf .*got -inf at row 0, column 1 \(2 such values\)$",
        ),
        (
            np.array([[1.0, 1e39]]),
            ValueError,
            r"^disparity must fit in float32 .*got 1e\+39 at row 0, column 1",
        ),
        (np.ones((2, 2, 3), np.float32), ValueError, r"^disparity must be a non-empty \(H, W\)"),
        (np.ones((0, 2), np.float32), ValueError, r"^disparity must be a non-empty \(H, W\)"),
        (np.ones((2, 2), np.uint16), TypeError, r"^disparity must have dtype float32 or float64"),
        (np.ma.masked_array(np.ones((2, 2))), TypeError, r"disparity"),
        ([[1.0, 2.0]], TypeError, r"^disparity must be a numpy.ndarray, got list"),
    ],
)
def test_write_disparity_pfm_refuses(
    tmp_path: Path, value: object, exc: type, message: str
) -> None:
    """A -inf is no disparity, and Middlebury would score it as one: refused, as any other
    bad map, naming the parameter and writing nothing."""
    (tmp_path / "d.pfm").write_bytes(b"keep")
    with pytest.raises(exc, match=message):
        io.write_disparity_pfm(tmp_path / "d.pfm", value)  # type: ignore[arg-type]
    assert (tmp_path / "d.pfm").read_bytes() == b"keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.pfm"]


def test_exported() -> None:
    assert {"write_disparity_pfm", "read_disparity_pfm"} <= set(io.__all__)


def test_the_web_pages_disparity_download_has_infinite_holes(tmp_path: Path) -> None:
    """The web page's disparity.pfm is a Middlebury disparity (+inf holes); its depth.pfm a
    plain PFM (a depth of +inf is disparity 0, a real value)."""
    pytest.importorskip("fastapi")
    from stereodepth.web import depthmap

    d = disparity()[:, :3]
    d[2, 2] = 0.0  # a point at infinity: depth +inf, kept in depth.pfm
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(d >= 0, 100.0 / d, np.nan).astype(np.float32)

    stored = SimpleNamespace(disparity=d, depth=depth)
    data = depthmap.download_bytes(stored, "disparity.pfm")  # type: ignore[arg-type]
    (tmp_path / "d.pfm").write_bytes(data)
    raw = io.read_pfm(tmp_path / "d.pfm")
    assert np.array_equal(raw == np.inf, ~np.isfinite(d))
    data = depthmap.download_bytes(stored, "depth.pfm")  # type: ignore[arg-type]
    (tmp_path / "z.pfm").write_bytes(data)
    np.testing.assert_array_equal(io.read_pfm(tmp_path / "z.pfm"), depth, strict=True)
