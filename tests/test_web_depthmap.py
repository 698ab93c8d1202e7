"""The web page's depth-map API through FastAPI's test client: the numbers are the library's
(disparity, depth, 3-D points, downloads), every bad upload answers at its field (never 500),
the limits hold, and two uploads at once both complete while the server keeps answering."""

from __future__ import annotations

import base64
import io
import struct
import threading
import zlib
from typing import Any

import numpy as np
import pytest

pytest.importorskip("fastapi", reason="the web extra is not installed")
pytest.importorskip("PIL", reason="decoding uploads needs Pillow")
pytest.importorskip("matplotlib", reason="the colour maps need the plot extra")

from fastapi.testclient import TestClient
from PIL import Image

import stereodepth.web.depthmap as depthmap
from stereodepth import block_match, disparity_to_depth, reproject
from stereodepth.io import read_disparity_pfm, read_image, read_pfm
from stereodepth.match_pair import default_num_disparities, prepare_pair, sgm_available
from stereodepth.sample import SAMPLE_BASELINE_MM, SAMPLE_FOCAL_PX, sample_pair
from stereodepth.web.app import create_app

#: The test client's address: the app answers only a Host that names this machine (DNS
#: rebinding), and the client's default, "testserver", does not.
LOCAL = "http://localhost"

RIG = {"baseline_mm": SAMPLE_BASELINE_MM, "focal_px": SAMPLE_FOCAL_PX}


@pytest.fixture(scope="module")
def client() -> TestClient:
    return TestClient(create_app(), base_url=LOCAL)


@pytest.fixture(scope="module")
def pair() -> Any:
    return sample_pair(96, 72, seed=4)


def encode(a: np.ndarray, fmt: str = "PNG", **kw: Any) -> str:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format=fmt, **kw)
    return base64.b64encode(buf.getvalue()).decode()


def b64(data: bytes) -> str:
    return base64.b64encode(data).decode()


def post(client: TestClient, **body: Any) -> Any:
    body.setdefault("rig", RIG)
    return client.post("/api/depthmap", json=body)


def f32(text: str, shape: tuple[int, int]) -> np.ndarray:
    return np.frombuffer(base64.b64decode(text), dtype="<f4").reshape(shape)


def same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and np.asarray(a, np.float32).tobytes() == b.tobytes()


def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png16_rgb(w: int, h: int, colour_type: int = 2) -> bytes:
    """A valid 16-bit RGB PNG, written by hand (colour type 2, bit depth 16; or 4, grey and
    alpha, fully opaque)."""
    pixel = bytes(6) if colour_type == 2 else b"\x12\x34\xff\xff"
    raw = b"".join(b"\x00" + pixel * w for _ in range(h))
    return (
        b"\x89PNG\r\n\x1a\n"
        + png_chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0))
        + png_chunk(b"IDAT", zlib.compress(raw))
        + png_chunk(b"IEND", b"")
    )


# --- the numbers are the library's -------------------------------------------------------------
def test_upload_gives_the_libraries_disparity_depth_and_points(
    client: TestClient, pair: Any
) -> None:
    r = post(client, left=encode(pair.left), right=encode(pair.right), disparity_step_px=0.25)
    assert r.status_code == 200, r.text
    body = r.json()
    h, w = pair.disparity.shape
    assert (body["width"], body["height"]) == (w, h)
    nd = default_num_disparities(w)
    assert body["params"] == {
        "num_disparities": nd,
        "min_disparity": 0,
        "block_size": 9,
        "cost": "census",
    }
    expected, confidence = block_match(
        pair.left, pair.right, num_disparities=nd, return_confidence=True
    )
    disparity = f32(body["arrays"]["disparity"], (h, w))
    depth = f32(body["arrays"]["depth"], (h, w))
    assert same(disparity, expected)
    assert same(f32(body["arrays"]["confidence"], (h, w)), confidence)
    lib_depth = disparity_to_depth(expected, focal_px=SAMPLE_FOCAL_PX, baseline_m=0.12)
    assert same(depth, lib_depth)  # bit for bit, NaN where NaN
    assert body["density"] == float(np.isfinite(expected).mean())
    assert body["rig"]["bf_m_px"] == SAMPLE_BASELINE_MM / 1000.0 * SAMPLE_FOCAL_PX
    assert body["rig"]["disparity_step_px"] == 0.25
    # Images: PNG data URLs of the right size.
    for key in ("left", "disparity", "depth"):
        head, _, data = body["images"][key].partition(",")
        assert head == "data:image/png;base64"
        with Image.open(io.BytesIO(base64.b64decode(data))) as im:
            assert im.size == (w, h) and im.mode == "RGB"
    # The point of a pixel: reproject's, at that pixel.
    points = reproject(expected, focal_px=SAMPLE_FOCAL_PX, baseline_m=0.12)
    y, x = np.argwhere(np.isfinite(expected))[len(np.argwhere(np.isfinite(expected))) // 2]
    pt = client.get(f"/api/depthmap/{body['id']}/point", params={"x": int(x), "y": int(y)}).json()
    assert pt["disparity_px"] == float(expected[y, x])
    assert pt["depth_m"] == float(lib_depth[y, x])
    assert pt["point_m"] == [float(v) for v in points[y, x]]
    assert pt["confidence"] == float(confidence[y, x])
    # The cloud: decimated valid points, coloured.
    cloud = body["points"]
    assert cloud["count"] == len(cloud["x"]) == len(base64.b64decode(cloud["rgb"])) // 3 > 0
    step = cloud["step"]
    sub = points[::step, ::step]
    kept = np.isfinite(sub).all(axis=-1)
    assert cloud["count"] == int(kept.sum())
    assert cloud["z"] == np.round(sub[kept][:, 2].astype(np.float64), 4).tolist()
    rgb = np.frombuffer(base64.b64decode(cloud["rgb"]), np.uint8).reshape(-1, 3)
    assert np.array_equal(rgb, pair.left[::step, ::step][kept])


@pytest.mark.parametrize("fmt", ["PNG", "JPEG"])
def test_an_exif_turned_upload_is_matched_as_displayed(
    client: TestClient, pair: Any, fmt: str
) -> None:
    # A phone stores the sensor's pixels and an orientation tag; the browser shows the turned
    # image, so the server must match that one (as read_image and cv2.imread read it), not
    # the stored pixels turned 90 degrees.
    exif = Image.Exif()
    exif[0x0112] = 6  # the stored image is to be rotated 90 degrees clockwise
    stored = [np.ascontiguousarray(np.rot90(img, 1)) for img in (pair.left, pair.right)]
    kw: dict[str, Any] = {"exif": exif, "quality": 100} if fmt == "JPEG" else {"exif": exif}
    r = post(client, left=encode(stored[0], fmt, **kw), right=encode(stored[1], fmt, **kw))
    assert r.status_code == 200, r.text
    body = r.json()
    h, w = pair.disparity.shape
    assert (body["width"], body["height"]) == (w, h)
    if fmt == "PNG":  # lossless: the very pair
        nd = default_num_disparities(w)
        expected = block_match(pair.left, pair.right, num_disparities=nd)
        assert same(f32(body["arrays"]["disparity"], (h, w)), expected)


def test_a_jpeg_with_a_second_image_is_read_as_its_first(client: TestClient, pair: Any) -> None:
    # Phone photos (a gain map, a depth map) and stereo cameras' .MPO files hold a second
    # image after the first; Pillow calls them MPO, and they were refused as "not a JPEG".
    # The first image is the photo (what browsers and read_image show).
    from PIL import JpegImagePlugin

    def mpo(a: np.ndarray) -> bytes:
        buf = io.BytesIO()
        extra = Image.fromarray(np.ascontiguousarray(a[::2, ::2]))
        Image.fromarray(a).save(buf, "MPO", save_all=True, append_images=[extra], quality=95)
        return buf.getvalue()

    files = [mpo(pair.left), mpo(pair.right)]
    assert Image.open(io.BytesIO(files[0])).format == "MPO"
    r = post(client, left=b64(files[0]), right=b64(files[1]))
    assert r.status_code == 200, r.text
    # The first image, decoded by Pillow's plain JPEG reader (which stops after it).
    first = [np.asarray(JpegImagePlugin.JpegImageFile(io.BytesIO(f))) for f in files]
    h, w = pair.disparity.shape
    expected = block_match(*first, num_disparities=default_num_disparities(w))
    assert same(f32(r.json()["arrays"]["disparity"], (h, w)), expected)


def test_a_12_bit_upload_is_shown_as_matched(client: TestClient, pair: Any) -> None:
    # A Mono12 pair in 16-bit PNGs: the page's image and the points' colours took the high
    # byte (0..15: black); they are now the min-max stretch the matcher applies.
    from stereodepth.colormap import to_uint8

    grey = [np.asarray(Image.fromarray(img).convert("L")) for img in (pair.left, pair.right)]
    l16, r16 = (g.astype(np.uint16) * 16 for g in grey)
    files = []
    for img in (l16, r16):
        buf = io.BytesIO()
        Image.fromarray(img).save(buf, format="PNG")
        files.append(base64.b64encode(buf.getvalue()).decode())
    r = post(client, left=files[0], right=files[1])
    assert r.status_code == 200, r.text
    body = r.json()
    _, _, data = body["images"]["left"].partition(",")
    with Image.open(io.BytesIO(base64.b64decode(data))) as im:
        shown = np.asarray(im.convert("L"))
    np.testing.assert_array_equal(shown, to_uint8(l16))
    assert shown.max() > 200
    rgb = np.frombuffer(base64.b64decode(body["points"]["rgb"]), np.uint8)
    assert rgb.max() > 200


def test_wrapped_base64_is_read(client: TestClient, pair: Any) -> None:
    # GNU base64 and openssl wrap at 76 columns (MIME, RFC 2045), with \n or \r\n: the same
    # pair, the same disparity (it used to be "not valid base64").
    plain = post(client, left=encode(pair.left), right=encode(pair.right)).json()
    left = encode(pair.left)
    wrapped = "\n".join(left[i : i + 76] for i in range(0, len(left), 76)) + "\n"
    right = encode(pair.right)
    crlf = "data:image/png;base64," + "\r\n".join(
        right[i : i + 64] for i in range(0, len(right), 64)
    )
    r = post(client, left=wrapped, right=crlf)
    assert r.status_code == 200, r.text
    assert r.json()["arrays"]["disparity"] == plain["arrays"]["disparity"]
    bad = post(client, left=wrapped.replace("\n", "\n!", 1), right=right)
    assert bad.status_code == 422 and "not valid base64" in bad.text


def test_downloads_are_the_libraries_files(client: TestClient, pair: Any, tmp_path: Any) -> None:
    body = post(client, left=encode(pair.left), right=encode(pair.right)).json()
    h, w = pair.disparity.shape
    disparity = f32(body["arrays"]["disparity"], (h, w))
    files = {}
    for name, url in body["downloads"].items():
        r = client.get(url)
        assert r.status_code == 200, name
        assert "attachment" in r.headers["content-disposition"]
        (tmp_path / name).write_bytes(r.content)
        files[name] = tmp_path / name
    # Middlebury's convention: +inf where there is no disparity (read back as NaN).
    assert same(read_disparity_pfm(files["disparity.pfm"]), disparity)
    assert np.array_equal(read_pfm(files["disparity.pfm"]) == np.inf, np.isnan(disparity))
    assert same(np.load(files["disparity.npy"]), disparity)
    depth = disparity_to_depth(disparity, focal_px=SAMPLE_FOCAL_PX, baseline_m=0.12)
    assert same(np.load(files["depth.npy"]), depth)
    assert same(read_pfm(files["depth.pfm"]), depth)
    mm = disparity_to_depth(disparity, focal_px=SAMPLE_FOCAL_PX, baseline_m=0.12, dtype=np.uint16)
    assert np.array_equal(read_image(files["depth-mm.png"]), mm)
    n = int(np.isfinite(disparity).sum())
    assert f"element vertex {n}\n".encode() in files["points.ply"].read_bytes()[:300]
    assert client.get(f"/api/depthmap/{body['id']}/secret.txt").status_code == 404
    assert client.get("/api/depthmap/nope/points.ply").status_code == 404
    r = client.get(f"/api/depthmap/{body['id']}/point", params={"x": w, "y": 0})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["query", "x"]
    # Not an integer, or missing: pydantic's message named neither the parameter nor the value.
    for params, msg in (
        ({"x": "1.5", "y": 0}, "x must be an integer, got 1.5"),
        ({"x": 0, "y": "1e3"}, "y must be an integer, got 1e3"),
        ({"x": "", "y": 0}, "x must be an integer, got an empty value"),
        ({"x": "left", "y": 0}, "x must be an integer, got 'left'"),
        ({"y": 0}, "x is required"),
        # twice: the last one was used without a word
        ({"x": [0, 5], "y": 0}, "x is given 2 times ('0', '5'): give it once"),
    ):
        r = client.get(f"/api/depthmap/{body['id']}/point", params=params)
        assert r.status_code == 422, r.text
        assert [e["msg"] for e in r.json()["detail"]] == [msg]


def test_principal_point_for_the_points(client: TestClient, pair: Any) -> None:
    body = post(client, left=encode(pair.left), right=encode(pair.right), cx_px=30.5, cy_px=20)
    assert body.status_code == 200, body.text
    b = body.json()
    assert (b["rig"]["cx_px"], b["rig"]["cy_px"]) == (30.5, 20.0)
    h, w = pair.disparity.shape
    disparity = f32(b["arrays"]["disparity"], (h, w))
    points = reproject(disparity, focal_px=SAMPLE_FOCAL_PX, baseline_m=0.12, cx_px=30.5, cy_px=20)
    y, x = np.argwhere(np.isfinite(disparity))[-1]
    pt = client.get(f"/api/depthmap/{b['id']}/point", params={"x": int(x), "y": int(y)}).json()
    assert pt["point_m"] == [float(v) for v in points[y, x]]
    ply = client.get(b["downloads"]["points.ply"]).content
    vertex = np.frombuffer(
        ply[ply.index(b"end_header\n") + 11 :], dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)]
    )
    assert np.array_equal(vertex["xyz"], points[np.isfinite(points).all(axis=-1)])


def test_calib_of_the_pairs_size_is_accepted(client: TestClient, pair: Any) -> None:
    h, w = pair.disparity.shape
    r = post(client, left=encode(pair.left), right=encode(pair.right), calib_size=[w, h])
    assert r.status_code == 200, r.text


def test_sample_pair_and_mixed_inputs(client: TestClient, pair: Any) -> None:
    r = post(client, sample=True)
    assert r.status_code == 200 and r.json()["sample"] is True
    s = sample_pair()
    got = f32(r.json()["arrays"]["disparity"], s.disparity.shape)
    expected = block_match(s.left, s.right, num_disparities=default_num_disparities(320))
    assert same(got, expected)
    ok = np.isfinite(expected)
    err = np.abs(expected[ok].astype(np.float64) - s.disparity[ok])
    assert r.json()["truth"] == {"mean_abs_error_px": err.mean(), "bad_1": (err > 1).mean()}
    assert r.json()["truth"]["bad_1"] < 0.01  # the sample is easy: the matcher finds it
    # A JPEG colour left and a grey PNG right: refused at the right image's field, the rule of
    # block_match and batch (both colour or both grey).
    grey = np.asarray(Image.fromarray(pair.right).convert("L"))
    left_jpeg = encode(pair.left, "JPEG", quality=95)
    r = post(client, left="data:image/jpeg;base64," + left_jpeg, right=encode(grey))
    assert r.status_code == 422, r.text
    assert "right must be colour (RGB) as left is, got a grey image" in r.text
    with pytest.raises(ValueError, match=r"^right must be colour \(RGB\) as left is"):
        prepare_pair(pair.left, grey)
    # 16-bit grey pairs are matched as 16-bit; an opaque alpha channel is dropped.
    l16 = (np.asarray(Image.fromarray(pair.left).convert("L"), np.uint16) * 257).astype(np.uint16)
    r16 = (grey.astype(np.uint16) * 257).astype(np.uint16)
    r = post(client, left=encode(l16), right=encode(r16), num_disparities=32, block_size=7)
    assert r.status_code == 200, r.text
    got = f32(r.json()["arrays"]["disparity"], grey.shape)
    assert same(got, block_match(l16, r16, num_disparities=32, block_size=7))
    rgba = np.dstack([pair.left, np.full(grey.shape, 255, np.uint8)])
    assert post(client, left=encode(rgba), right=encode(pair.right)).status_code == 200


def test_middlebury_calib_fills_the_rig(client: TestClient) -> None:
    text = "cam0=[1733.74 0 792.27; 0 1733.74 541.89; 0 0 1]\ndoffs=0\nbaseline=536.62\n"
    text += "width=1920\nheight=1080\nndisp=170\n"
    r = client.post("/api/calib", json={"calib": text})
    assert r.status_code == 200
    assert r.json() == {
        "focal_px": 1733.74,
        "baseline_mm": 536.62,
        "doffs_px": 0.0,
        "width_px": 1920,
        "height_px": 1080,
        "ndisp": 170,
        "cx_px": 792.27,
        "cy_px": 541.89,
    }
    for bad, msg in [
        ("baseline=1\n", "calib: calib.txt: missing field 'cam0'"),
        ("cam0=[1 2; 3 4]\nbaseline=3\n", "cam0 must be a 3x3 matrix"),
        ("", "calib must be the text of a Middlebury calib.txt, got an empty text"),
    ]:
        r = client.post("/api/calib", json={"calib": bad})
        assert r.status_code == 422
        (item,) = r.json()["detail"]
        assert item["loc"] == ["body", "calib"] and msg in item["msg"], item
        assert "/tmp" not in item["msg"]  # the server's temporary path is not shown
    # A lone surrogate (valid JSON, not encodable text) was a 500 writing the temporary file.
    r = client.post(
        "/api/calib",
        content=b'{"calib": "cam0=[1 0 0; 0 1 0; 0 0 1]\\ud800"}',
        headers={"content-type": "application/json"},
    )
    assert r.status_code == 422, r.text
    (item,) = r.json()["detail"]
    assert item["loc"] == ["body", "calib"]
    assert item["msg"] == "calib: the text is not valid Unicode ('\\ud800')"


# --- every bad input: 422 (or 413) at its field, never 500 ------------------------------------
def bad_cases(pair: Any) -> list[tuple[dict[str, Any], list[Any], str]]:
    left, right = encode(pair.left), encode(pair.right)
    png = base64.b64decode(left)
    gif = io.BytesIO()
    Image.fromarray(pair.left).convert("P").save(gif, format="GIF")
    transparent = np.dstack([pair.left, np.full(pair.disparity.shape, 255, np.uint8)])
    transparent[0, 0, 3] = 0
    l16 = np.zeros(pair.disparity.shape, np.uint16)
    return [
        (
            {"left": b64(b"just some text"), "right": right},
            ["body", "left"],
            "left: not an image Pillow can read; give a PNG or JPEG file, got 14 bytes of text "
            "beginning 'just some text'",
        ),
        (
            {"left": left, "right": encode(pair.right[:, :90])},
            ["body", "right"],
            "right must have the size of left, 96x72 px, got 90x72 px",
        ),
        (
            {"left": b64(png[: len(png) // 2]), "right": right},
            ["body", "left"],
            "left: the image is truncated or damaged",
        ),
        (
            {"left": left, "right": b64(png16_rgb(96, 72))},
            ["body", "right"],
            "right: 16-bit colour PNGs are not supported",
        ),
        (
            # Pillow keeps the high byte of 16-bit grey and alpha: it was matched as 8-bit
            {"left": left, "right": b64(png16_rgb(96, 72, colour_type=4))},
            ["body", "right"],
            "right: 16-bit grey and alpha PNGs are not supported",
        ),
        (
            {"left": encode(transparent), "right": right},
            ["body", "left"],
            "left: the image has transparent pixels",
        ),
        (
            {"left": b64(gif.getvalue()), "right": right},
            ["body", "left"],
            "left: must be a PNG or JPEG image, got GIF",
        ),
        (
            {"left": encode(l16), "right": encode(pair.right[..., 1].copy())},
            ["body", "right"],
            "right must have the bit depth of left (16-bit), got 8-bit",
        ),
        ({"right": right}, ["body", "left"], "left is required: choose an image file"),
        ({"left": left, "right": left}, ["body", "right"], "right: the same file as left"),
        ({"left": "%%%not base64", "right": right}, ["body", "left"], "left: not valid base64"),
        ({"left": b64(b""), "right": right}, ["body", "left"], "left: the file is empty"),
        ({"left": 5, "right": right}, ["body", "left"], "left must be the image file as base64"),
        (
            {"left": left, "right": right, "rig": {"baseline_mm": -1, "focal_px": 700}},
            ["body", "rig", "baseline_mm"],
            "baseline_mm must be a number > 0",
        ),
        (
            {"left": left, "right": right, "rig": {"baseline_mm": 1, "focal_px": "x"}},
            ["body", "rig", "focal_px"],
            "focal_px must be a number > 0",
        ),
        (
            {"left": left, "right": right, "rig": {"baseline_mm": 100, "focal_mm": 4}},
            ["body", "rig", "pixel_um"],
            "pixel_um is required",
        ),
        (
            {"left": left, "right": right, "rig": {"focal_px": 700}},
            ["body", "rig", "baseline_mm"],
            "baseline_mm is required",
        ),
        ({"left": left, "right": right, "rig": "150"}, ["body", "rig"], "rig must be an object"),
        (
            {"left": left, "right": right, "num_disparities": "abc"},
            ["body", "num_disparities"],
            "num_disparities must be an integer from 1 to 4096, got 'abc'",
        ),
        (
            {"left": left, "right": right, "num_disparities": 0},
            ["body", "num_disparities"],
            "num_disparities must be an integer from 1 to 4096, got 0",
        ),
        (
            {"left": left, "right": right, "block_size": 4},
            ["body", "block_size"],
            "block_size must be an odd integer",
        ),
        ({"left": left, "right": right, "cost": "ssd"}, ["body", "cost"], "cost must be census"),
        # Unhashable values were answered "unhashable type: 'dict'" at the body, not the field.
        ({"left": left, "right": right, "cost": {}}, ["body", "cost"], "cost must be census"),
        ({"left": left, "right": right, "cost": ["sad"]}, ["body", "cost"], "cost must be census"),
        ({"left": left, "right": right, "method": "x"}, ["body", "method"], "method must be bm"),
        (
            {"left": left, "right": right, "disparity_step_px": 0},
            ["body", "disparity_step_px"],
            "disparity_step_px must be a number > 0",
        ),
        ({"sample": "yes"}, ["body", "sample"], "sample must be true or false"),
        (  # the uploads were ignored without a word: the answer was the sample's
            {"sample": True, "left": left},
            ["body", "left"],
            "left: give the images or sample: true, not both",
        ),
        ({"sample": True, "cx_px": "abc"}, ["body", "cx_px"], "cx_px must be a finite number"),
        ({"sample": True, "cy_px": "inf"}, ["body", "cy_px"], "cy_px must be a finite number"),
        ({"sample": True, "cx_px": 1e308}, ["body", "cx_px"], "cx_px must be a finite number"),
        ({"sample": True, "cy_px": "-2e6"}, ["body", "cy_px"], "magnitude at most 1e+06"),
        (  # the calib.txt of the full-size images with a smaller pair: every depth scaled
            {"left": left, "right": right, "calib_size": [192, 144]},
            ["body", "calib"],
            "calib: the calib.txt is for 192\u00d7144 px images, the pair is 96\u00d772 px",
        ),
        (  # beside the sample pair (320x240) it was ignored without a word
            {"sample": True, "calib_size": [707, 481]},
            ["body", "calib"],
            "calib: the calib.txt is for 707\u00d7481 px images, the pair is 320\u00d7240 px",
        ),
        (
            {"sample": True, "calib_size": [96, "72"]},
            ["body", "calib_size"],
            "calib_size must be [width, height], two integers > 0, got [96, '72']",
        ),
        ({"sample": True, "calib_size": [0, 72]}, ["body", "calib_size"], "two integers > 0"),
        # JSON integers beyond a double's range were a 500 (OverflowError in float()).
        ({"sample": True, "cx_px": 10**400}, ["body", "cx_px"], "cx_px must be a finite number"),
        (
            {"sample": True, "rig": {"baseline_mm": 10**400, "focal_px": 700}},
            ["body", "rig", "baseline_mm"],
            "baseline_mm must be a number > 0",
        ),
        (
            {"sample": True, "disparity_step_px": -(10**400)},
            ["body", "disparity_step_px"],
            "disparity_step_px must be a number > 0",
        ),
        # Misspelt fields were ignored: the default search range, or a rig without its doffs
        # (every depth wrong), without a word.
        (
            {"sample": True, "num_disparity": 64},
            ["body", "num_disparity"],
            "num_disparity is not a field of /api/depthmap, got 64 (its fields: left, right, ",
        ),
        (
            {"sample": True, "rig": {**RIG, "doffs": 31.3}},
            ["body", "rig", "doffs"],
            "doffs is not a field of rig, got 31.3 (its fields: baseline_mm, focal_mm, pixel_um, "
            "focal_px, doffs_px)",
        ),
    ]


def test_every_bad_upload_is_answered_at_its_field(client: TestClient, pair: Any) -> None:
    for body, loc, message in bad_cases(pair):
        r = post(client, **body)
        assert r.status_code == 422, (loc, r.text)
        details = r.json()["detail"]
        found = [d for d in details if d["loc"] == loc]
        assert found, (loc, details)
        assert message in found[0]["msg"], (message, found[0]["msg"])


def test_sgm_where_missing(client: TestClient, pair: Any) -> None:
    r = post(client, left=encode(pair.left), right=encode(pair.right), method="sgm")
    if sgm_available():
        assert r.status_code == 200
    else:
        assert r.status_code == 422
        assert r.json()["detail"][0]["loc"] == ["body", "method"]


def test_without_matplotlib_a_clear_answer_not_500(
    pair: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib raises
    r = TestClient(create_app(), base_url=LOCAL).post(
        "/api/depthmap", json={"sample": True, "rig": RIG}
    )
    assert r.status_code == 503
    assert r.json()["detail"][0]["msg"] == (
        'colour maps need matplotlib: pip install "stereodepth[plot]"'
    )


def test_limits_take_numpy_integers_and_name_bad_ones() -> None:
    # A numpy integer limit (from a config array) was refused as 'max_upload_bytes must be
    # an integer >= 1, got np.int64(5)'; a float 2.5 was a ValueError, not a TypeError.
    limits = depthmap.DepthMapLimits(max_upload_bytes=np.int64(5), max_pixels=np.int32(7))
    assert (limits.max_upload_bytes, limits.max_pixels) == (5, 7)
    assert type(limits.max_upload_bytes) is int
    with pytest.raises(TypeError, match=r"max_pixels must be an integer, got float 2\.5"):
        depthmap.DepthMapLimits(max_pixels=2.5)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="max_pixels must be an integer, got bool True"):
        depthmap.DepthMapLimits(max_pixels=True)
    with pytest.raises(ValueError, match="max_upload_bytes must be an integer >= 1, got 0"):
        create_app(max_upload_bytes=0)


def test_limits_give_each_methods_defaults(client: TestClient) -> None:
    """The page's form held block matching's block size (9) and cost for every method, so
    choosing semi-global matching sent both and was refused ('cost is an option of method
    bm'); the limits now give each method's own defaults, those of the library's matchers."""
    import inspect

    from stereodepth import block_match, semi_global_match

    defaults = client.get("/api/depthmap/limits").json()["defaults"]
    bm = inspect.signature(block_match).parameters
    assert defaults["bm"] == {"block_size": bm["block_size"].default, "cost": bm["cost"].default}
    if sgm_available():
        sgm = inspect.signature(semi_global_match).parameters
        assert "cost" not in sgm
        assert defaults["sgm"] == {"block_size": sgm["block_size"].default, "cost": None}


@pytest.mark.parametrize("baseline_mm", [1.0, 1e-6])
def test_the_cloud_of_a_small_rig_keeps_its_shape(client: TestClient, baseline_mm: float) -> None:
    """The cloud's coordinates were rounded to 0.1 mm whatever the scene's size: with a 1 mm
    baseline (a stereo microscope) the sample's points stood on a coarse grid, with 1 nm all
    at 0. They keep 5 significant digits of the largest coordinate; a metre-sized scene
    keeps 0.1 mm (the test above)."""
    r = post(client, sample=True, rig={"baseline_mm": baseline_mm, "focal_px": SAMPLE_FOCAL_PX})
    assert r.status_code == 200, r.text
    body = r.json()
    cloud = body["points"]
    h, w = body["height"], body["width"]
    disparity = f32(body["arrays"]["disparity"], (h, w))
    points = reproject(disparity, focal_px=SAMPLE_FOCAL_PX, baseline_m=baseline_mm / 1000)
    sub = points[:: cloud["step"], :: cloud["step"]]
    want = sub[np.isfinite(sub).all(axis=-1)].astype(np.float64)
    got = np.array([cloud["x"], cloud["y"], cloud["z"]]).T
    assert got.shape == want.shape
    extent = np.abs(want).max()
    np.testing.assert_allclose(got, want, rtol=0, atol=extent * 5e-5)
    assert len(np.unique(got[:, 2])) > 10  # the depths are not one value


def test_sgm_block_size_1(client: TestClient, pair: Any) -> None:
    """semi_global_match takes block_size 1 (a pixel-wise cost) or 3, but the request's
    block_size had to be from 3 on (block matching's smallest): 1 was refused, so the page
    could not run semi-global matching pixel-wise. Now 1 reaches the matcher; block matching
    still refuses it, naming block_size."""
    if not sgm_available():
        pytest.skip("this build has no semi-global matcher")
    from stereodepth import semi_global_match

    r = post(client, sample=True, method="sgm", block_size=1, num_disparities=48)
    assert r.status_code == 200, r.text
    s = sample_pair()
    want = semi_global_match(s.left, s.right, num_disparities=48, block_size=1)
    assert same(f32(r.json()["arrays"]["disparity"], want.shape), want)
    assert r.json()["params"]["block_size"] == 1
    r = post(client, sample=True, method="bm", block_size=1)
    assert r.status_code == 422
    (item,) = r.json()["detail"]
    assert item["loc"] == ["body", "block_size"] and "got 1" in item["msg"], item


def test_sgm_with_a_stand_in_matcher(
    client: TestClient, pair: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    import stereodepth

    def stand_in(left: Any, right: Any, *, num_disparities: int, min_disparity: int = 0) -> Any:
        return block_match(left, right, num_disparities=num_disparities)

    monkeypatch.setattr(stereodepth, "semi_global_match", stand_in, raising=False)
    assert client.get("/api/depthmap/limits").json()["methods"] == ["bm", "sgm"]
    r = post(
        client,
        left=encode(pair.left),
        right=encode(pair.right),
        method="sgm",
        cost=None,
        block_size=None,
        num_disparities=24,
    )
    assert r.status_code == 200, r.text
    b = r.json()
    assert b["method"] == "sgm" and b["arrays"]["confidence"] is None
    h, w = pair.disparity.shape
    assert same(
        f32(b["arrays"]["disparity"], (h, w)), stand_in(pair.left, pair.right, num_disparities=24)
    )
    r = post(client, left=encode(pair.left), right=encode(pair.right), method="sgm", block_size=5)
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["body", "block_size"]


def test_not_json_and_not_an_object(client: TestClient) -> None:
    r = client.post("/api/depthmap", content=b"{nope", headers={"content-type": "application/json"})
    assert r.status_code == 422
    assert r.json()["detail"][0]["msg"] == (
        "the request must be JSON, got text that is not: Expecting property name enclosed in "
        "double quotes at line 1 column 2"
    )
    r = client.post("/api/depthmap", json=[1, 2])
    assert r.status_code == 422
    assert r.json()["detail"][0]["msg"] == "the request must be a JSON object, got an array"
    # JSON nested deeper than Python's recursion limit was a 500 (RecursionError).
    deep = b"[" * 100_000 + b"]" * 100_000
    for url in ("/api/depthmap", "/api/calib"):
        r = client.post(url, content=deep, headers={"content-type": "application/json"})
        assert r.status_code == 422, (url, r.text)
        assert r.json()["detail"][0]["msg"] == "the request must be JSON nested less deeply"


def test_a_key_given_twice_in_the_json_is_refused_at_it(client: TestClient, pair: Any) -> None:
    """JSON keeps the last of two equal keys without a word: {"num_disparities": 16,
    "num_disparities": 64} searched 64, a rig with two baselines used the second. Each
    answers 422 at that field with both values, as a query parameter given twice does."""
    left, right = encode(pair.left), encode(pair.right)
    rig = f'{{"baseline_mm": {SAMPLE_BASELINE_MM}, "focal_px": {SAMPLE_FOCAL_PX}}}'
    cases = [
        (
            f'{{"left": "{left}", "right": "{right}", "rig": {rig}, "num_disparities": 16, '
            '"num_disparities": 64}',
            ["body", "num_disparities"],
            "num_disparities is given twice (16, 64): give it once",
        ),
        (
            f'{{"left": "{left}", "right": "{right}", "rig": {{"baseline_mm": 100, '
            f'"focal_px": {SAMPLE_FOCAL_PX}, "baseline_mm": 120}}}}',
            ["body", "rig", "baseline_mm"],
            "baseline_mm is given twice (100, 120): give it once",
        ),
    ]
    for text, loc, msg in cases:
        r = client.post(
            "/api/depthmap", content=text.encode(), headers={"content-type": "application/json"}
        )
        assert r.status_code == 422, r.text
        assert r.json()["detail"] == [{"loc": loc, "msg": msg, "type": "repeated"}]
    r = client.post(
        "/api/calib",
        content=b'{"calib": "doffs=0", "calib": "baseline=1"}',
        headers={"content-type": "application/json"},
    )
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["body", "calib"]
    assert "calib is given twice ('doffs=0', 'baseline=1')" in r.json()["detail"][0]["msg"]
    # The same request with each key once is answered.
    r = client.post(
        "/api/depthmap",
        content=cases[0][0].replace(', "num_disparities": 64', "").encode(),
        headers={"content-type": "application/json"},
    )
    assert r.status_code == 200 and r.json()["params"]["num_disparities"] == 16


def test_a_body_not_sent_as_json_is_refused(client: TestClient) -> None:
    """The routes read their body themselves, so FastAPI's refusal of a JSON body sent as
    another type (its CSRF guard) did not apply: a text/plain or form POST, which any web
    site may make a browser send to 127.0.0.1 without a CORS preflight, was matched. 415."""
    body = b'{"sample": true, "rig": {"baseline_mm": 100, "focal_px": 500}}'
    for url in ("/api/depthmap", "/api/calib"):
        for kind in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data"):
            r = client.post(url, content=body, headers={"content-type": kind})
            assert r.status_code == 415, (url, kind, r.text)
            (item,) = r.json()["detail"]
            assert item["loc"] == ["header", "content-type"] and repr(kind) in item["msg"]
    r = client.post("/api/depthmap", content=body)  # no content-type at all
    assert r.status_code == 415
    for kind in ("application/json", "application/json; charset=utf-8", "Application/JSON"):
        r = client.post("/api/depthmap", content=body, headers={"content-type": kind})
        assert r.status_code == 200, (kind, r.text)


def test_limits_in_bytes_and_pixels(pair: Any) -> None:
    left, right = encode(pair.left), encode(pair.right)
    size = len(base64.b64decode(left))
    small = TestClient(create_app(max_upload_bytes=size - 1, max_pixels=96 * 72), base_url=LOCAL)
    r = small.post("/api/depthmap", json={"left": left, "right": right, "rig": RIG})
    assert r.status_code == 422
    item = r.json()["detail"][0]
    assert item["loc"] == ["body", "left"] and "more than the limit of" in item["msg"]
    assert item["type"] == "too_large"
    limits = small.get("/api/depthmap/limits").json()
    assert (limits["max_upload_bytes"], limits["max_pixels"]) == (size - 1, 96 * 72)
    # A body larger than two images may be is refused before it is read whole.
    big = "A" * (depthmap.DepthMapLimits(size - 1).max_body_bytes + 10)
    r = small.post("/api/depthmap", json={"left": big, "right": right, "rig": RIG})
    assert r.status_code == 413 and r.json()["detail"][0]["type"] == "too_large"
    # Pixels: one pixel more than the limit.
    tight = TestClient(create_app(max_pixels=96 * 72 - 1), base_url=LOCAL)
    r = tight.post("/api/depthmap", json={"left": left, "right": right, "rig": RIG})
    assert r.status_code == 422
    msg = r.json()["detail"][0]["msg"]
    assert msg.startswith("left: the image is 96x72 px") and "more than the limit" in msg
    # An image beyond what Pillow opens safely (a decompression bomb) is too large too.
    bomb = (
        b"\x89PNG\r\n\x1a\n"
        + png_chunk(b"IHDR", struct.pack(">IIBBBBB", 20000, 20000, 8, 0, 0, 0, 0))
        + png_chunk(b"IDAT", zlib.compress(b""))
        + png_chunk(b"IEND", b"")
    )
    huge = TestClient(create_app(max_pixels=10**9), base_url=LOCAL)
    r = huge.post("/api/depthmap", json={"left": b64(bomb), "right": right, "rig": RIG})
    assert r.status_code == 422
    item = r.json()["detail"][0]
    assert item["loc"] == ["body", "left"] and item["type"] == "too_large", item
    with pytest.raises(ValueError, match="max_pixels must be an integer >= 1, got 0"):
        create_app(max_pixels=0)


def test_two_uploads_at_once_both_complete_and_the_server_keeps_answering(
    pair: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Both jobs wait inside the worker threads until /api/calc has answered: the calculator
    answers while matching runs, and then both uploads complete."""
    calc_answered = threading.Event()
    started = threading.Barrier(3, timeout=30)
    real = depthmap.compute

    def slow_compute(job: Any) -> Any:
        started.wait()
        assert calc_answered.wait(timeout=30)
        return real(job)

    monkeypatch.setattr(depthmap, "compute", slow_compute)
    left, right = encode(pair.left), encode(pair.right)
    grey_left = encode(np.asarray(Image.fromarray(pair.left).convert("L")))
    grey_right = encode(np.asarray(Image.fromarray(pair.right).convert("L")))
    answers: dict[int, Any] = {}
    with TestClient(create_app(), base_url=LOCAL) as c:

        def upload(i: int, left_b64: str, right_b64: str) -> None:
            answers[i] = c.post(
                "/api/depthmap", json={"left": left_b64, "right": right_b64, "rig": RIG}
            )

        threads = [
            threading.Thread(target=upload, args=(0, left, right)),
            threading.Thread(target=upload, args=(1, grey_left, grey_right)),
        ]
        for t in threads:
            t.start()
        started.wait()  # both jobs are in their worker threads
        r = c.get("/api/calc", params={"baseline_mm": 120, "focal_px": 700, "disparity_px": 30})
        assert r.status_code == 200
        calc_answered.set()
        for t in threads:
            t.join(timeout=60)
    assert answers[0].status_code == 200 and answers[1].status_code == 200
    assert answers[0].json()["id"] != answers[1].json()["id"]


# --- each message names its field and what was received -----------------------------------------
def messages_cases() -> list[Any]:
    """(body, loc, the whole message): messages that had named neither the field nor what
    came (in the comments: what they said before)."""
    pair = sample_pair(96, 72, seed=4)
    left, right = encode(pair.left), encode(pair.right)
    png = base64.b64decode(left)
    rig_fields = "baseline_mm, focal_mm, pixel_um, focal_px, doffs_px"
    return [
        pytest.param(  # "rig must be an object with the calculator's fields"
            {"sample": True, "rig": None},
            ["body", "rig"],
            "rig is required: an object with baseline_mm, and focal_px (and doffs_px) or "
            "focal_mm and pixel_um",
            id="rig-missing",
        ),
        pytest.param(
            {"sample": True, "rig": [150, 700]},
            ["body", "rig"],
            f"rig must be an object with the calculator's fields ({rig_fields}), got an array",
            id="rig-array",
        ),
        pytest.param(  # a 401-digit number, shown whole
            {"sample": True, "rig": {"baseline_mm": 10**400, "focal_px": 700}},
            ["body", "rig", "baseline_mm"],
            "baseline_mm must be a number > 0 and <= 1000000, got 10000000000000000000... "
            "(401 digits)",
            id="huge-integer",
        ),
        pytest.param(  # at ["body", "rig"], not at the field
            {"sample": True, "rig": {"baseline_mm": 1e-300, "focal_px": 1e-300}},
            ["body", "rig", "baseline_mm"],
            "baseline_mm=1e-300 with a focal length of 1e-300 px gives B*f = 0.0 m*px, outside "
            "the range of a double",
            id="rig-library-error",
        ),
        pytest.param(  # at ["body"]: the library's focal_px * baseline_m and float64 advice
            {"sample": True, "rig": {"baseline_mm": 1, "focal_mm": 1e-300, "pixel_um": 1000}},
            ["body", "rig"],
            "rig: focal length 1e-300 px times baseline 0.001 m is 1e-303 px*m, outside the range "
            "float32 depth maps can be computed from ([1.175e-38, 3.403e+38] px*m): check the "
            "units",
            id="rig-float32",
        ),
        pytest.param(  # "doffs_px goes with focal_px (a calibration in pixels)"
            {
                "sample": True,
                "rig": {"baseline_mm": 1, "focal_mm": 4, "pixel_um": 2, "doffs_px": 3},
            },
            ["body", "rig", "doffs_px"],
            "doffs_px goes with focal_px (a calibration in pixels), got doffs_px 3 with focal_mm "
            "and pixel_um",
            id="doffs-with-mm",
        ),
        pytest.param(  # got True
            {"sample": True, "num_disparities": True},
            ["body", "num_disparities"],
            "num_disparities must be an integer from 1 to 4096, got true",
            id="json-true",
        ),
        pytest.param(  # the whole string, however long
            {"sample": True, "method": "x" * 1000},
            ["body", "method"],
            f"method must be bm or sgm, got {'x' * 40 + '...'!r}",
            id="long-string",
        ),
        pytest.param(  # got inf (the number it became)
            {"sample": True, "cx_px": 10**400},
            ["body", "cx_px"],
            "cx_px must be a finite number (px) of magnitude at most 1e+06, got "
            "10000000000000000000... (401 digits)",
            id="principal-point-as-sent",
        ),
        pytest.param(  # "left: choose an image file"
            {"right": right},
            ["body", "left"],
            "left is required: choose an image file (or sample: true)",
            id="image-missing",
        ),
        pytest.param(  # "left: give the image file as base64 text"
            {"left": 5, "right": right},
            ["body", "left"],
            "left must be the image file as base64 text (or a data: URL), got the number 5",
            id="image-not-text",
        ),
        pytest.param(  # "left: a data URL must be base64"
            {"left": "data:image/png," + left, "right": right},
            ["body", "left"],
            "left: a data URL must be base64 (data:<type>;base64,<data>), got 'data:image/png'",
            id="data-url-not-base64",
        ),
        pytest.param(  # "left: not valid base64"
            {"left": left[:10] + "-" + left[11:], "right": right},
            ["body", "left"],
            "left: not valid base64, got '-' at character 11 (base64 has A-Z, a-z, 0-9, + and /, "
            "and = at the end)",
            id="base64-character",
        ),
        pytest.param(
            {"left": "QUJDRA=", "right": right},
            ["body", "left"],
            "left: not valid base64, got 7 characters (1 of them = at the end): the text is cut "
            "short or its = padding is wrong",
            id="base64-padding",
        ),
        pytest.param(  # "left: not an image Pillow can read; give a PNG or JPEG file"
            {"left": b64(b"\x00\x01\x02\x03\xfe\xff\x00\x00\x00"), "right": right},
            ["body", "left"],
            "left: not an image Pillow can read; give a PNG or JPEG file, got 9 bytes beginning "
            "00 01 02 03 fe ff 00 00",
            id="binary-not-image",
        ),
        pytest.param(  # the same: a PNG cut inside its header (the size is before the cut)
            {"left": b64(png[:30]), "right": right},
            ["body", "left"],
            "left: the image is truncated or damaged: a PNG file of 30 bytes (96x72 px by its "
            "header) that Pillow cannot read",
            id="png-cut-short",
        ),
        *upload_cases(pair, png),
    ]


def png_header(w: int, h: int) -> bytes:
    """A PNG of w x h px by its header, with no pixels (a decompression bomb's shape)."""
    return (
        b"\x89PNG\r\n\x1a\n"
        + png_chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
        + png_chunk(b"IDAT", zlib.compress(b""))
        + png_chunk(b"IEND", b"")
    )


def grey_transparent(pair: Any) -> list[tuple[int, bytes, int]]:
    """(bits, PNG bytes, transparent pixel count): 8- and 16-bit grey PNGs of the pair's left
    grey image whose transparency chunk names a grey level some pixels have."""
    grey8 = np.ascontiguousarray(pair.left[..., 1]) if pair.left.ndim == 3 else pair.left
    out = []
    for bits, grey in ((8, grey8), (16, grey8.astype(np.uint16) * 257)):
        key = int(grey[0, 0])
        buf = io.BytesIO()
        Image.fromarray(grey).save(buf, format="PNG", transparency=key)
        out.append((bits, buf.getvalue(), int((grey == key).sum())))
    return out


def upload_cases(pair: Any, png: bytes) -> list[Any]:
    """Upload messages that did not say what came (in the comments: what they said)."""
    right = encode(pair.right)
    pfm = b"Pf\n10 8\n-1.0\n" + bytes(4 * 80)
    gif = io.BytesIO()
    Image.fromarray(pair.left).convert("P").save(gif, format="GIF")
    pgm = b"P5\n96 72\n255\n" + pair.left.tobytes()
    jpeg = bytearray(base64.b64decode(encode(pair.left, "JPEG")))
    sof = jpeg.index(b"\xff\xc0")  # the frame header: precision, height, width
    jpeg[sof + 5 : sof + 9] = struct.pack(">HH", 50000, 60000)
    transparent = np.dstack([pair.left, np.full(pair.disparity.shape, 255, np.uint8)])
    transparent[:2, :3, 3] = 0
    fields = (
        "left, right, sample, rig, method, num_disparities, block_size, cost, disparity_step_px, "
        "cx_px, cy_px, calib_size"
    )
    return [
        pytest.param(  # "got PPM": Pillow's name for the Netpbm family, which holds PFM
            {"left": b64(pfm), "right": right},
            ["body", "left"],
            f"left: must be a PNG or JPEG image, got PFM (10x8 px, {len(pfm)} bytes): PFM holds "
            "floating-point maps, such as the disparity.pfm this page and `stereodepth match` "
            "write, not an image to match",
            id="pfm",
        ),
        pytest.param(  # "got PPM"
            {"left": b64(pgm), "right": right},
            ["body", "left"],
            f"left: must be a PNG or JPEG image, got PGM (96x72 px, {len(pgm)} bytes)",
            id="pgm",
        ),
        pytest.param(  # "got GIF"
            {"left": b64(gif.getvalue()), "right": right},
            ["body", "left"],
            f"left: must be a PNG or JPEG image, got GIF (96x72 px, {len(gif.getvalue())} bytes)",
            id="gif",
        ),
        pytest.param(  # "right: the same file as left": two empty files, right not named empty
            {"left": b64(b""), "right": b64(b"")},
            ["body", "right"],
            "right: the file is empty (0 bytes); choose an image file",
            id="both-empty",
        ),
        pytest.param(
            {"left": b64(b""), "right": right},
            ["body", "left"],
            "left: the file is empty (0 bytes); choose an image file",
            id="empty",
        ),
        pytest.param(  # not "the same file as left": right's own problem
            {"left": b64(pfm), "right": b64(pfm)},
            ["body", "right"],
            f"right: must be a PNG or JPEG image, got PFM (10x8 px, {len(pfm)} bytes): PFM holds "
            "floating-point maps, such as the disparity.pfm this page and `stereodepth match` "
            "write, not an image to match",
            id="both-pfm",
        ),
        pytest.param(
            {"left": b64(png), "right": b64(png)},
            ["body", "right"],
            f"right: the same file as left, byte for byte (a PNG file of {len(png)} bytes (96x72 "
            "px by its header)); choose the other image",
            id="same-file",
        ),
        pytest.param(  # "the image has more pixels than Pillow opens safely, more than ..."
            {"left": b64(png_header(60000, 60000)), "right": right},
            ["body", "left"],
            "left: the image is 60000x60000 px (3.6e+03 MP), more than the limit of 4 MP",
            id="png-too-many-pixels",
        ),
        pytest.param(  # the same
            {"left": b64(bytes(jpeg)), "right": right},
            ["body", "left"],
            "left: the image is 60000x50000 px (3e+03 MP), more than the limit of 4 MP",
            id="jpeg-too-many-pixels",
        ),
        pytest.param(
            {"left": encode(transparent), "right": right},
            ["body", "left"],
            "left: the image has transparent pixels (an alpha channel): 6 of its 96x72 px are "
            "not opaque; give an opaque image",
            id="transparent",
        ),
        *(
            pytest.param(  # a grey PNG's transparency chunk was taken as opaque
                {"left": b64(grey_trns), "right": right},
                ["body", "left"],
                f"left: the image has transparent pixels (an alpha channel): {n} of its 96x72 px "
                "are not opaque; give an opaque image",
                id=f"transparent-grey-{bits}",
            )
            for bits, grey_trns, n in grey_transparent(pair)
        ),
        pytest.param(
            {"left": encode(pair.left), "right": b64(png16_rgb(96, 72))},
            ["body", "right"],
            "right: 16-bit colour PNGs are not supported, got one of 96x72 px; give 8-bit colour "
            "or 16-bit grey",
            id="png-16-bit-colour",
        ),
        pytest.param(  # repr cut at 40 characters, its closing quote with it
            {"left_image": "A" * 100, "sample": True},
            ["body", "left_image"],
            f"left_image is not a field of /api/depthmap, got {'A' * 40 + '...'!r} (its fields: "
            f"{fields})",
            id="unknown-field-long-value",
        ),
    ]


@pytest.mark.parametrize(("body", "loc", "msg"), messages_cases())
def test_each_message_names_the_field_and_what_was_received(
    client: TestClient, body: dict[str, Any], loc: list[str], msg: str
) -> None:
    r = post(client, **body)
    assert r.status_code == 422, r.text
    found = [d for d in r.json()["detail"] if d["loc"] == loc]
    assert found, r.json()
    assert found[0]["msg"] == msg


def test_a_rig_without_a_focal_length_is_missing_as_in_the_calculator(client: TestClient) -> None:
    # /api/calc answers a rig without a focal length at focal_mm and pixel_um with type
    # "missing" (the page marks the input it shows by it); the depth map's answer had the
    # same messages as "value_error".
    r = post(client, sample=True, rig={"baseline_mm": 120, "doffs_px": ""})
    assert r.status_code == 422, r.text
    calc = client.get("/api/calc", params={"baseline_mm": 120}).json()["detail"]
    assert r.json()["detail"] == [
        {**d, "loc": ["body", "rig", d["loc"][1]], "type": "missing"} for d in calc
    ]


def test_a_truncated_image_is_named_with_its_size(client: TestClient, pair: Any) -> None:
    # "left: the image is truncated or damaged (image file is truncated ...)": Pillow's words
    # (in parentheses, as Pillow has them) after the file's.
    png = base64.b64decode(encode(pair.left))
    cut = png[: len(png) - 200]
    r = post(client, left=b64(cut), right=encode(pair.right))
    assert r.status_code == 422, r.text
    (item,) = r.json()["detail"]
    assert item["loc"] == ["body", "left"]
    assert item["msg"].startswith(
        f"left: the image is truncated or damaged: a 96x72 px PNG file of {len(cut)} bytes "
        "that Pillow cannot decode ("
    ), item["msg"]


def test_beyond_pillows_limit_the_message_gives_the_size(pair: Any) -> None:
    # Under a server limit above Pillow's (--max-megapixels 1000): "the image has more pixels
    # than Pillow opens safely" gave neither the size nor Pillow's limit.
    huge = TestClient(create_app(max_pixels=10**9), base_url=LOCAL)
    r = huge.post(
        "/api/depthmap",
        json={"left": b64(png_header(20000, 20000)), "right": encode(pair.right), "rig": RIG},
    )
    assert r.status_code == 422, r.text
    pillow = f"{Image.MAX_IMAGE_PIXELS / 1e6:.3g} MP"
    assert r.json()["detail"] == [
        {
            "loc": ["body", "left"],
            "msg": f"left: the image is 20000x20000 px (400 MP), more than Pillow opens safely, "
            f"{pillow}",
            "type": "too_large",
        }
    ]


@pytest.mark.parametrize(
    ("method", "url", "loc", "msg"),
    [
        pytest.param(  # ignored: the answer was pixel (1, 2)'s
            "GET",
            "/api/depthmap/{key}/point?x=1&y=2&z=3",
            "z",
            "z is not a parameter of /api/depthmap/{key}/point, got '3' (its parameters: x, y)",
            id="point",
        ),
        pytest.param(
            "GET",
            "/api/depthmap/{key}/point?x=1&y=2&X=4&X=5",
            "X",
            "X is not a parameter of /api/depthmap/{key}/point, got '4', '5' (its parameters: "
            "x, y)",
            id="point-case",
        ),
        pytest.param(
            "GET",
            "/api/depthmap/{key}/depth.npy?format=pfm",
            "format",
            "format is not a parameter of /api/depthmap/{key}/{name}, got 'pfm' (it takes none)",
            id="download",
        ),
        pytest.param(
            "GET",
            "/api/depthmap/limits?max_pixels=1",
            "max_pixels",
            "max_pixels is not a parameter of /api/depthmap/limits, got '1' (it takes none)",
            id="limits",
        ),
        pytest.param(  # the search range asked for in the URL was not the one used
            "POST",
            "/api/depthmap?num_disparities=64",
            "num_disparities",
            "num_disparities is not a parameter of /api/depthmap, got '64' (it takes none: its "
            "fields go in the JSON body)",
            id="depthmap",
        ),
        pytest.param(
            "POST",
            "/api/calib?calib=calib.txt",
            "calib",
            "calib is not a parameter of /api/calib, got 'calib.txt' (it takes none: its fields "
            "go in the JSON body)",
            id="calib",
        ),
    ],
)
def test_every_route_refuses_a_query_parameter_it_does_not_have(
    client: TestClient, method: str, url: str, loc: str, msg: str
) -> None:
    # As /api/calc does; each of these answered as if it had not been given.
    key = client.post("/api/depthmap", json={"sample": True, "rig": RIG}).json()["id"]
    body = {"calib": "x"} if "calib" in url else {"sample": True, "rig": RIG}
    r = client.request(method, url.replace("{key}", key), json=body if method == "POST" else None)
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == [{"loc": ["query", loc], "msg": msg, "type": "extra_forbidden"}]
    # Without it, the same request is answered.
    r = client.request(
        method,
        url.replace("{key}", key).split("?")[0] + ("?x=1&y=2" if "point" in url else ""),
        json=body if method == "POST" else None,
    )
    assert r.status_code == (422 if "calib" in url else 200), r.text


def test_null_is_the_default_for_method_and_sample(client: TestClient, pair: Any) -> None:
    # As for the other fields; they were "method must be bm or sgm, got None" and "sample
    # must be true or false, got None".
    r = post(client, left=encode(pair.left), right=encode(pair.right), method=None, sample=None)
    assert r.status_code == 200, r.text
    assert r.json()["method"] == "bm" and r.json()["sample"] is False


@pytest.mark.parametrize(
    ("content", "msg"),
    [
        pytest.param(b"", "the request must be JSON, got an empty body", id="empty"),
        pytest.param(
            b'{"sample": tru}',
            "the request must be JSON, got text that is not: Expecting value at line 1 column 12",
            id="not-json",
        ),
        pytest.param(
            b'{"sample": "\xff"}',
            "the request must be JSON in UTF-8, got byte 0xff at position 12",
            id="not-utf8",
        ),
        pytest.param(
            b'{"num_disparities": ' + b"9" * 5000 + b"}",
            "the request must be JSON whose integers have at most 4300 digits, got one with more",
            id="integer-too-long",
        ),
        pytest.param(b"[1, 2]", "the request must be a JSON object, got an array", id="array"),
        pytest.param(b"NaN", "the request must be a JSON object, got the number nan", id="nan"),
        pytest.param(b'"left"', "the request must be a JSON object, got a string", id="string"),
        pytest.param(b"null", "the request must be a JSON object, got null", id="null"),
    ],
)
@pytest.mark.parametrize("url", ["/api/depthmap", "/api/calib"])
def test_a_body_that_is_not_a_json_object_is_named(
    client: TestClient, url: str, content: bytes, msg: str
) -> None:
    # Each was "the request must be JSON" or "the request must be a JSON object".
    r = client.post(url, content=content, headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == [{"loc": ["body"], "msg": msg, "type": "value_error"}]


@pytest.mark.parametrize(
    ("body", "status", "loc", "msg"),
    [
        pytest.param(  # "calib: give the text of a Middlebury calib.txt"
            {},
            422,
            ["body", "calib"],
            "calib is required: the text of a Middlebury calib.txt",
            id="missing",
        ),
        pytest.param(
            {"calib": ["baseline=1"]},
            422,
            ["body", "calib"],
            "calib must be the text of a Middlebury calib.txt, got an array",
            id="array",
        ),
        pytest.param(
            {"calib": " \n"},
            422,
            ["body", "calib"],
            "calib must be the text of a Middlebury calib.txt, got an empty text",
            id="blank",
        ),
        pytest.param(  # ignored: the answer was "give the text of a Middlebury calib.txt"
            {"calib_txt": "baseline=1"},
            422,
            ["body", "calib_txt"],
            "calib_txt is not a field of /api/calib, got 'baseline=1' (its fields: calib)",
            id="misspelt",
        ),
        pytest.param(  # "calib: a calib.txt is a few lines; this file is too large"
            {"calib": "#" * 150_000},
            422,
            ["body", "calib"],
            "calib: a calib.txt is a few lines; this one is 150000 characters, more than the "
            "limit of 100000",
            id="long",
        ),
        pytest.param(  # "calib: the file is too large"
            {"calib": "#" * 250_000},
            413,
            ["body", "calib"],
            "calib: the file is too large: the request is more than 200000 bytes (a calib.txt "
            "is a few lines)",
            id="too-large",
        ),
    ],
)
def test_calib_messages_name_what_was_received(
    client: TestClient, body: dict[str, Any], status: int, loc: list[str], msg: str
) -> None:
    r = client.post("/api/calib", json=body)
    assert r.status_code == status, r.text
    (item,) = r.json()["detail"]
    assert item["loc"] == loc and item["msg"] == msg, item


def test_unknown_results_and_files_are_named(client: TestClient) -> None:
    # Both were "no such result or file" at ["path"] (and "no such result (or too old)").
    r = client.post("/api/depthmap", json={"sample": True, "rig": RIG})
    key = r.json()["id"]
    gone = (
        "key: no result 'nope'; the server keeps the last 6 depth maps (and none across a "
        "restart): compute it again"
    )
    for url in ("/api/depthmap/nope/point?x=1&y=1", "/api/depthmap/nope/depth.npy"):
        r = client.get(url)
        assert r.status_code == 404, url
        assert r.json()["detail"] == [{"loc": ["path", "key"], "msg": gone, "type": "value_error"}]
    r = client.get(f"/api/depthmap/{key}/depth.txt")
    assert r.status_code == 404
    (item,) = r.json()["detail"]
    assert item["loc"] == ["path", "name"]
    assert item["msg"] == (
        "name must be one of disparity.pfm, disparity.npy, depth.npy, depth.pfm, depth-mm.png, "
        "points.ply, got 'depth.txt'"
    )
