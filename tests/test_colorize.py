"""stereodepth.colorize and save_colorized: a tiny map coloured by hand, limits, clipping,
NaN, the figure's colour bar, and one test per rejected input."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="the plot extra is not installed")

import matplotlib

import stereodepth
from stereodepth import colorize, save_colorized
from stereodepth.colormap import (
    COLORBAR_HEIGHT_PX,
    LUT_SIZE,
    colorize_limits,
    colormap_lut,
    preview_image,
)


def colour(name: str, k: int) -> list[int]:
    """The k-th of 256 colours of matplotlib's map, by hand: cmap(k / 255), rounded."""
    r, g, b, _ = matplotlib.colormaps[name](k / 255.0)
    return [round(r * 255), round(g * 255), round(b * 255)]


def test_tiny_map_by_hand() -> None:
    values = np.array([[0.0, 1.0, 2.0], [np.nan, 3.0, 4.0], [1.5, np.inf, -np.inf]])
    got = colorize(values, vmin=1.0, vmax=3.0, invalid_color=(255, 0, 255))
    assert got.dtype == np.uint8 and got.shape == (3, 3, 3)
    # t = (v - 1) / 2 clipped to [0, 1]; k = rint(255 t): 0 -> 0 (clipped), 1 -> 0,
    # 2 -> rint(127.5) = 128, 3 -> 255, 4 -> 255 (clipped), 1.5 -> rint(63.75) = 64.
    expected = [
        [colour("turbo", 0), colour("turbo", 0), colour("turbo", 128)],
        [[255, 0, 255], colour("turbo", 255), colour("turbo", 255)],
        [colour("turbo", 64), [255, 0, 255], [255, 0, 255]],
    ]
    assert got.tolist() == expected


def test_other_map_and_integer_input() -> None:
    values = np.array([[10, 20], [30, 40]], dtype=np.uint16)
    got = colorize(values, cmap="gray", vmin=10, vmax=40)
    # gray is r = g = b = k: 0, 85, 170, 255.
    assert got[..., 0].tolist() == [[0, 85], [170, 255]]
    assert (got[..., 0] == got[..., 1]).all() and (got[..., 1] == got[..., 2]).all()
    assert colorize(values, cmap=matplotlib.colormaps["gray"], vmin=10, vmax=40).tolist() == (
        got.tolist()
    )


def test_default_limits_are_the_1st_and_99th_percentiles() -> None:
    rng = np.random.default_rng(3)
    values = rng.normal(20, 5, (40, 50))
    values[0, :5] = np.nan
    values[1, 0] = 1e6  # an outlier does not wash the map out
    finite = values[np.isfinite(values)]
    lo, hi = np.percentile(finite, [1, 99])
    assert colorize_limits(values) == (lo, hi)
    assert colorize(values).tolist() == colorize(values, vmin=lo, vmax=hi).tolist()
    # One limit given, the other a percentile.
    assert colorize_limits(values, vmin=0) == (0.0, hi)
    assert colorize_limits(values, vmax=30) == (lo, 30.0)


def test_all_invalid_and_constant_maps() -> None:
    nan = np.full((2, 3), np.nan)
    assert (colorize(nan, invalid_color=(1, 2, 3)) == [1, 2, 3]).all()
    assert colorize_limits(nan) == (0.0, 1.0)
    flat = np.full((2, 2), 7.0)
    assert colorize_limits(flat) == (7.0, 7.0)
    assert (colorize(flat) == colour("turbo", 128)).all()  # the middle colour
    # A given limit beyond every value: both limits at that value; the values below it.
    assert colorize_limits(flat, vmin=9) == (9.0, 9.0)
    assert (colorize(flat, vmin=9) == colour("turbo", 0)).all()


def test_values_near_the_float64_limits() -> None:
    # hi - lo and the percentiles' interpolation overflow float64 here: no warning (pytest
    # runs with -W error), no IndexError; the lowest, middle and highest colours.
    big = np.finfo(np.float64).max / 1.05
    values = np.array([[-big, 0.0, big, np.nan]])
    got = colorize(values, vmin=-big, vmax=big)
    assert got[0].tolist() == [
        colour("turbo", 0),
        colour("turbo", 128),
        colour("turbo", 255),
        [0, 0, 0],
    ]
    lo, hi = colorize_limits(values)
    assert np.isfinite([lo, hi]).all() and -big < lo < 0 < hi < big
    assert colorize(values)[0, :3].tolist() == got[0, :3].tolist()
    # float32 maps near their own limit are computed in float64 and do not overflow.
    f32 = np.array([[-3e38, 0.0, 3e38]], dtype=np.float32)
    assert colorize(f32)[0].tolist() == got[0, :3].tolist()


def test_lut_is_matplotlibs_sampled() -> None:
    lut = colormap_lut("viridis")
    assert lut.shape == (LUT_SIZE, 3) and lut.dtype == np.uint8
    assert lut[0].tolist() == colour("viridis", 0) and lut[200].tolist() == colour("viridis", 200)


def test_exported_from_the_package() -> None:
    assert stereodepth.colorize is colorize and "colorize" in stereodepth.__all__


def test_save_colorized_writes_the_map_and_a_colour_bar(tmp_path: Path) -> None:
    from PIL import Image

    values = np.linspace(0, 50, 37 * 61).reshape(37, 61).astype(np.float32)
    values[3, 4] = np.nan
    out = save_colorized(tmp_path / "d.png", values, quantity="depth", unit="m", vmin=5, vmax=45)
    assert out == tmp_path / "d.png"
    with Image.open(out) as im:
        assert im.mode == "RGB" and im.size == (61, 37 + COLORBAR_HEIGHT_PX)
        a = np.asarray(im)
    assert a[:37].tolist() == colorize(values, vmin=5, vmax=45).tolist()
    assert a[37:].min() < 128  # something (bar and text) is drawn on the white strip
    assert a.tolist() == preview_image(values, label="depth (m)", vmin=5, vmax=45).tolist()
    assert [p.name for p in tmp_path.iterdir()] == ["d.png"]  # no temporary file left


@pytest.mark.parametrize(
    "ends",
    [(-1.7e308, 1.7e308), (1.7976931348623157e308, 1.7976931348623157e308), (-1e305, 0.0)],
)
def test_save_colorized_values_near_a_doubles_limits(
    tmp_path: Path, ends: tuple[float, float]
) -> None:
    """colorize maps values near float64's limits (its halved arithmetic), but the colour bar
    under them failed: matplotlib's 'overflow encountered in scalar subtract', then 'Axis
    limits cannot be NaN or Inf', naming nothing. The bar is drawn in units of a power of ten
    that its label names; the map above it is colorize's, pixel for pixel."""
    from PIL import Image

    half = np.linspace(1.0, 0.0, 15 * 200)  # ends[1] - ends[0] may overflow
    values = np.concatenate([ends[0] * half, ends[1] * half[::-1]]).reshape(30, 200)
    out = save_colorized(tmp_path / "d.png", values, quantity="depth", unit="m")
    with Image.open(out) as im:
        a = np.asarray(im)
    assert a.shape == (30 + COLORBAR_HEIGHT_PX, 200, 3)
    assert a[:30].tolist() == colorize(values).tolist()
    assert a[30:].min() < 128


# --- rejected input: one test per kind ---------------------------------------------------------
@pytest.mark.parametrize(
    ("values", "kind", "message"),
    [
        ("abc", TypeError, "values must be a 2-D array of real numbers"),
        (
            np.zeros((2, 2), dtype=bool),
            TypeError,
            "values must be a 2-D array of real numbers, got bool",
        ),
        (np.zeros((2, 2), dtype=complex), TypeError, "dtype complex128"),
        ([[1, 2], [3]], TypeError, "values must be a 2-D array"),
        (np.zeros(5), ValueError, "values must be a non-empty 2-D (H, W) array, got shape (5,)"),
        (np.zeros((0, 4)), ValueError, "got shape (0, 4)"),
        (np.zeros((2, 2, 3)), ValueError, "got shape (2, 2, 3)"),
    ],
)
def test_bad_values(values: Any, kind: type[Exception], message: str) -> None:
    with pytest.raises(kind, match=None) as info:
        colorize(values)
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("kwargs", "kind", "message"),
    [
        ({"vmin": "1"}, TypeError, "vmin must be a real number or None, got str '1'"),
        ({"vmax": True}, TypeError, "vmax must be a real number or None, got bool True"),
        ({"vmin": float("nan")}, ValueError, "vmin must be finite, got nan"),
        ({"vmax": float("inf")}, ValueError, "vmax must be finite, got inf"),
        # An int beyond a double was Python's OverflowError 'int too large to convert to float'.
        (
            {"vmin": 10**400},
            ValueError,
            "vmin must be within the range of a double (about 1.8e308), got an integer of 401",
        ),
        ({"vmax": -(10**309)}, ValueError, "vmax must be within the range of a double"),
        ({"vmin": 3, "vmax": 3}, ValueError, "vmin must be < vmax, got vmin=3.0 and vmax=3.0"),
        ({"vmin": 4, "vmax": 1}, ValueError, "vmin must be < vmax"),
        ({"cmap": "no-such-map"}, ValueError, "cmap must be a matplotlib colour map name"),
        ({"cmap": 3}, TypeError, "cmap must be a colour map name or a matplotlib Colormap"),
        ({"invalid_color": (0, 0)}, ValueError, "invalid_color must be three integers"),
        ({"invalid_color": (0, 0, 256)}, ValueError, "got (0, 0, 256)"),
        ({"invalid_color": (0, 0, 0.5)}, TypeError, "invalid_color must be three integers"),
        ({"invalid_color": "red"}, TypeError, "invalid_color must be three integers"),
        ({"invalid_color": 5}, TypeError, "got int 5"),
    ],
)
def test_bad_options(kwargs: dict[str, Any], kind: type[Exception], message: str) -> None:
    with pytest.raises(kind) as info:
        colorize(np.ones((2, 2)), **kwargs)
    assert message in str(info.value)


@pytest.mark.parametrize(
    ("path", "kwargs", "kind", "message"),
    [
        ("d.jpg", {}, ValueError, "path must end in .png"),
        ("missing/d.png", {}, ValueError, "path's folder must exist"),
        ("d.png", {"unit": 3}, TypeError, "unit must be a str"),
    ],
)
def test_save_colorized_bad_input(
    tmp_path: Path, path: str, kwargs: dict[str, Any], kind: type[Exception], message: str
) -> None:
    with pytest.raises(kind) as info:
        save_colorized(tmp_path / path, np.ones((2, 2)), **kwargs)
    assert message in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_without_matplotlib_one_line_with_the_install_hint(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib raises ImportError
    with pytest.raises(ImportError) as info:
        colorize(np.ones((2, 2)))
    assert str(info.value) == 'colour maps need matplotlib: pip install "stereodepth[plot]"'


def test_to_uint8_stretches_16_bit_images_as_the_matchers_do() -> None:
    from stereodepth.colormap import to_uint8

    rng = np.random.default_rng(3)
    twelve = rng.integers(100, 4096, (5, 7)).astype(np.uint16)  # a Mono12 camera's range
    twelve[0, 0], twelve[0, 1] = 100, 4095
    got = to_uint8(twelve)
    assert got.dtype == np.uint8 and got.shape == twelve.shape
    want = np.floor((twelve.astype(np.float64) - 100) * 255 / (4095 - 100) + 0.5)
    assert np.abs(got.astype(np.float64) - want).max() <= 1  # float32 rounding at .5 ties
    assert got.min() == 0 and got.max() == 255  # the high byte gave 0..15
    rgb16 = np.dstack([twelve, twelve // 2, twelve * 16])  # one stretch for all channels
    assert to_uint8(rgb16).shape == rgb16.shape and to_uint8(rgb16).max() == 255
    flat = np.full((2, 3), 0x1234, np.uint16)
    assert (to_uint8(flat) == 0x12).all()  # constant: its high byte
    u8 = np.arange(6, dtype=np.uint8).reshape(2, 3)
    assert to_uint8(u8) is u8
    assert to_uint8(np.zeros((0, 4), np.uint16)).shape == (0, 4)
    with pytest.raises(TypeError, match="image must have dtype uint8 or uint16, got float32"):
        to_uint8(np.zeros((2, 2), np.float32))
