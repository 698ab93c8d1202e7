"""stereodepth.io.write_disparity_png16: KITTI's round(d * 256), half up, 0 for no value."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereodepth import io


def test_disparity_png16_rounds_half_up_as_the_docstring_and_kittis_devkit(
    tmp_path: Path,
) -> None:
    """The docstring says only values below 1/512 px become holes, but numpy's rint rounds
    half to even: exactly 1/512 px (0.5 after * 256) became 0, a hole. KITTI's disp_write.m
    rounds with MATLAB's uint16(), half away from zero: 1/512 -> 1, 3/512 -> 2, 5/512 -> 3."""
    d = np.array(
        [
            [1 / 512, 3 / 512, 5 / 512, 1 / 512 - 2**-30],
            [100 + 1 / 512, 255 + 509 / 512, 255 + 507 / 512, 0.0],
        ]
    )
    io.write_disparity_png16(tmp_path / "d.png", d)
    got = io.read_image(tmp_path / "d.png")
    assert got.tolist() == [[1, 2, 3, 0], [25601, 65535, 65534, 0]]
    back = io.read_disparity_png16(tmp_path / "d.png")
    assert back[0, 0] == np.float32(1 / 256) and np.isnan(back[0, 3])
    # 255 + 511/512 px is 65535.5 * 1/256, rounded up to 65536: beyond the format, refused
    with pytest.raises(ValueError, match=r"disparity up to 255\.998 px does not fit"):
        io.write_disparity_png16(tmp_path / "e.png", np.array([[255 + 511 / 512]]))
    assert not (tmp_path / "e.png").exists()


def test_disparity_png16_rounds_exactly_next_to_a_half(tmp_path: Path) -> None:
    # float64 disparities one ulp either side of a half step: floor(x + 0.5) rounded the sum
    # first, so that just below 1/512 px (x = 0.49999999999999994) became 1.
    halves = (np.arange(0, 65535) + 0.5) / 256
    below = np.nextafter(halves, 0)
    above = np.nextafter(halves, np.inf)
    d = np.stack([below, above])[:, :65534]
    io.write_disparity_png16(tmp_path / "d.png", d)
    got = io.read_image(tmp_path / "d.png").astype(np.int64)
    k = np.arange(65534)
    assert (got[0] == k).all()  # just below (k + 1/2) / 256 px: k (0, a hole, for k = 0)
    assert (got[1] == k + 1).all()
