"""End to end: ``stereodepth serve`` as a real server on a free loopback port, then the page in
a real headless Chromium (Playwright driving the system's ``chromium``).

The browser is found as $STEREODEPTH_CHROMIUM, else ``chromium`` or ``chromium-browser`` on the
PATH; without one (or without Playwright) the browser tests skip and say why. Screenshots go to
tests/artifacts/ (printed; look at them).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from server_process import ServerProcess, serve

from stereodepth import StereoRig
from stereodepth.cli import main

pytest.importorskip("fastapi", reason="the web extra is not installed")

ARTIFACTS = Path(__file__).resolve().parent / "artifacts"
ARM = {
    "baseline_mm": "150",
    "focal_mm": "6",
    "pixel_um": "2.8",
    "width_px": "1280",
    "disparity_px": "250",
}
ARM_ARGS = ["--baseline-mm", "150", "--focal-mm", "6", "--pixel-um", "2.8", "--width-px", "1280"]
START_TIMEOUT_S = 30


def get_json(url: str) -> tuple[int, Any]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


# --- the real server -----------------------------------------------------------------------------
def test_serve_listens_on_loopback_answers_and_stops() -> None:
    server = serve("--port", "0")
    try:
        assert server.url.startswith("http://127.0.0.1:")
        assert "the calculator is at" in server.first_line
        status, body = get_json(
            server.url + "api/calc?baseline_mm=150&focal_mm=6&pixel_um=2.8"
            "&width_px=1280&disparity_px=250"
        )
        assert status == 200
        assert body["summary"] == json.loads(
            json.dumps(StereoRig(150, 6, 2.8, width_px=1280).summary(250))
        )
        status, body = get_json(server.url + "api/calc?baseline_mm=-1&focal_mm=6&pixel_um=2.8")
        assert status == 422 and body["detail"][0]["loc"] == ["query", "baseline_mm"]
        with urllib.request.urlopen(server.url, timeout=10) as r:
            assert b"Stereo depth calculator" in r.read()
    finally:
        code, _, _, err = server.stop()
    assert code == 0, err


def test_serve_open_opens_the_page(tmp_path: Path) -> None:
    opened = tmp_path / "opened.txt"
    # webbrowser runs $BROWSER with the URL for %s: here, a script that notes it.
    fake = f"{sys.executable} -c \"import sys; open(sys.argv[1], 'w').write(sys.argv[2])\""
    server = serve("--port", "0", "--open", env={"BROWSER": f"{fake} {opened} %s"})
    try:
        for _ in range(100):
            if opened.exists() and opened.read_text():
                break
            time.sleep(0.1)
        assert opened.read_text() == server.url
    finally:
        code, _, _, err = server.stop()
    assert code == 0, err


ALLOW_HOST_RULE = (
    "--allow-host must be a host name or IP address, optionally with :PORT (1 to 65535), or '*'"
)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--port", "70000"], "--port must be an integer from 0 to 65535, got 70000"),
        (["--host", "no.such.host.invalid"], "--host must be an address of this machine"),
        # an address, but another machine's (TEST-NET-1): the address is the problem, not
        # the port
        (["--host", "192.0.2.1"], "--host 192.0.2.1 is not an address of this machine ("),
        (["--host", "[2001:db8::1]"], "--host [2001:db8::1] is not an address of this machine"),
        (["--host", "[192.0.2.1]"], "--host must be an address of this machine, got '[192.0.2"),
        (["--max-upload-mb", "0"], "--max-upload-mb must be a number > 0 and <= 10000, got 0"),
        (["--max-megapixels", "nan"], "--max-megapixels must be a number > 0 and <= 10000"),
        (["--allow-host", "x:port"], f"{ALLOW_HOST_RULE}, got 'x:port'"),
        (["--allow-host", "localhost:0"], f"{ALLOW_HOST_RULE}, got 'localhost:0'"),
        (["--allow-host", ""], f"{ALLOW_HOST_RULE}, got ''"),
        (["--allow-host", "*.lan"], f"{ALLOW_HOST_RULE}, got '*.lan'"),  # no wildcards
        (["--allow-host", "a,b"], f"{ALLOW_HOST_RULE}, got 'a,b'"),
        (
            ["--allow-host", "é..local", "--port", "70000"],  # refused before the port
            f"{ALLOW_HOST_RULE}, got 'é..local' (IDNA cannot encode it: label empty or too long)",
        ),
        (["--allow-host", "http://box:8080/"], f"{ALLOW_HOST_RULE}, got 'http://box:8080/'"),
        # each one, before the server listens (on a --port it could not take)
        (
            ["--allow-host", "box", "--allow-host", "[::1", "--port", "70000"],
            f"{ALLOW_HOST_RULE}, got '[::1'",
        ),
    ],
)
def test_serve_rejects_bad_options(
    capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    assert main(["serve", *args]) == 2
    out, err = capsys.readouterr()
    assert err.startswith(f"stereodepth serve: error: {message}")
    assert err.count("\n") == 1 and out == "", (out, err)
    if args[0] == "--host":
        assert "--port" not in err, err


def test_serve_reports_a_busy_port(capsys: pytest.CaptureFixture[str]) -> None:
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        assert main(["serve", "--port", str(port)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"stereodepth serve: error: cannot listen on 127.0.0.1 port {port}")
    assert "--port" in err


# --- the page in a real browser ------------------------------------------------------------------
def chromium_executable() -> str | None:
    env = os.environ.get("STEREODEPTH_CHROMIUM")
    if env:
        return env if Path(env).is_file() else None
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return None


@pytest.fixture(scope="module")
def server() -> Iterator[ServerProcess]:
    s = serve("--port", "0")
    yield s
    code, _, _, err = s.stop()
    assert code == 0, err


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="Playwright for Python is not installed"
    )
    exe = chromium_executable()
    if exe is None:
        pytest.skip(
            "no Chromium: install Debian's chromium package or set "
            "STEREODEPTH_CHROMIUM to its executable"
        )
    # A loaded 2-core machine may take seconds to start plotly.js: wait up to 20 s.
    sync_api.expect.set_options(timeout=20_000)
    with sync_api.sync_playwright() as pw:
        # --no-sandbox: Chromium's sandbox cannot start as root in a container.
        b = pw.chromium.launch(
            executable_path=exe, args=["--no-sandbox", "--disable-dev-shm-usage"]
        )
        yield b
        b.close()


class Page:
    """A browser page on the server, which records every request and console error."""

    def __init__(self, context: Any, url: str) -> None:
        self.url = url
        self.requests: list[str] = []
        self.errors: list[str] = []

        def route(r: Any) -> None:
            self.requests.append(r.request.url)
            if r.request.url.startswith(url):
                r.continue_()
            else:  # the page must work offline: nothing may leave this machine
                r.abort()

        self.page = context.new_page()
        self.page.route("**/*", route)
        self.page.on("pageerror", lambda e: self.errors.append(f"page error: {e}"))
        self.page.on("console", self._console)
        self.page.goto(url, wait_until="domcontentloaded")  # the charts come later
        self.expect(self.page.locator("#status")).to_have_text("Up to date.")

    def _console(self, msg: Any) -> None:
        # A 422 answer is logged by Chromium as a failed resource: that is the page working.
        if msg.type == "error" and "status of 422" not in msg.text:
            self.errors.append(f"console: {msg.text}")

    @staticmethod
    def expect(locator: Any) -> Any:
        from playwright.sync_api import expect

        return expect(locator)

    def value(self, key: str) -> str:
        return str(self.page.locator(f"#out-{key} .value").inner_text())

    def fill(self, values: dict[str, str]) -> None:
        for name, v in values.items():
            self.page.fill(f"#{name}", v)

    def screenshot(self, name: str) -> Path:
        ARTIFACTS.mkdir(exist_ok=True)
        self.page.mouse.move(0, 0)  # no hover effects in the picture
        path = ARTIFACTS / name
        self.page.screenshot(path=str(path), full_page=True)
        print(f"screenshot: {path}")
        return path

    def close(self) -> None:
        assert all(u.startswith(self.url) for u in self.requests), self.requests
        assert self.errors == []
        self.page.close()


@pytest.fixture(scope="module")
def context(browser: Any) -> Iterator[Any]:
    """One browser profile for the module, so plotly.js is fetched once (it is cached)."""
    c = browser.new_context(viewport={"width": 1440, "height": 900})
    yield c
    c.close()


@pytest.fixture
def page(context: Any, server: ServerProcess) -> Iterator[Page]:
    p = Page(context, server.url)
    yield p
    p.close()


def cli_text(*args: str) -> str:
    proc = subprocess.run(
        [sys.executable, "-m", "stereodepth.cli", "calc", *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return proc.stdout


def cli_value(text: str, label: str) -> str:
    found = re.search(rf"^{re.escape(label)}\s+(\S+)", text, re.M)
    assert found, (label, text)
    return found.group(1)


@pytest.mark.browser
def test_example_1_results_table_and_charts(page: Page) -> None:
    p = page.page
    p.click("#preset-car")
    page.expect(p.locator("#out-depth_m .value")).to_have_text("20.4082")
    page.expect(p.locator("#preset-car")).to_have_attribute("aria-pressed", "true")

    page.fill(ARM)  # typed in, as a user would
    page.expect(p.locator("#out-depth_m .value")).to_have_text("1.28571")
    page.expect(p.locator("#preset-arm")).to_have_attribute("aria-pressed", "true")
    page.expect(p.locator("#preset-car")).to_have_attribute("aria-pressed", "false")
    assert round(float(page.value("depth_m")), 2) == 1.29
    page.expect(p.locator("#status")).to_have_text("Up to date.")

    # The page shows the CLI's digits.
    text = cli_text(
        *ARM_ARGS, "--disparity-px", "250", "--subpixel-px", "0.25", "--max-disparity-px", "256"
    )
    for key, label in [
        ("depth_m", "depth"),
        ("disparity_mm", "disparity on the sensor"),
        ("depth_resolution_m", "depth resolution (1 px)"),
        ("max_depth_m", "max depth (1 px disparity)"),
        ("focal_px", "focal length"),
        ("depth_resolution_subpx_m", "depth resolution (0.25 px)"),
        ("min_depth_m", "min depth (search to 256 px)"),
    ]:
        assert page.value(key) == cli_value(text, label), key
    assert page.value("hfov_deg") == f"{StereoRig(150, 6, 2.8, width_px=1280).hfov_deg:.6g}"

    # The table: the library's rows, the target's row marked.
    summary = StereoRig(150, 6, 2.8, width_px=1280).summary(250, disparity_step_px=0.25)
    rows = p.locator("#depth-table tbody tr")
    page.expect(rows).to_have_count(len(summary["table"]))
    first = rows.nth(0).locator("td").all_inner_texts()
    assert first[0] == "1" and first[2] == f"{summary['table'][0]['depth_m']:.6g}"
    assert p.locator("#depth-table tbody tr.near td").first.inner_text() == "256"
    headers = p.locator("#depth-table thead th").all_inner_texts()
    assert headers[0] == "Disparity d (px)" and headers[-1] == "Depth resolution, 0.25 px (m)"

    # The charts: drawn by plotly into SVG, with the curves and the marked target.
    for chart_id, n_series in [("chart-depth", 1), ("chart-error", 2)]:
        chart = p.locator(f"#{chart_id}")
        page.expect(chart.locator(".scatterlayer .trace")).to_have_count(n_series + n_series)
        drawn = p.evaluate(
            f"""() => document.getElementById('{chart_id}').data.map(
                t => ({{name: t.name, n: t.x.length, x: t.x[0], y: t.y[0]}}))"""
        )
        assert len(drawn) == 2 * n_series
        assert all(t["n"] > 0 for t in drawn)
        # Each curve is a drawn SVG line across most of the plot's width (plotly simplifies a
        # straight line on log axes to a few points).
        widths = p.evaluate(
            f"""() => {{
                const gd = document.getElementById('{chart_id}');
                return [...gd.querySelectorAll('.scatterlayer .trace path.js-line')]
                    .map(e => e.getBBox().width / gd._fullLayout._size.w);
            }}"""
        )
        assert len(widths) == n_series and all(w > 0.8 for w in widths), widths
        assert chart.locator(".annotation-text").count() == n_series
    markers = {
        t["name"]: t
        for t in p.evaluate(
            """() => ['chart-depth', 'chart-error'].flatMap(id => document.getElementById(id).data
               .filter(t => t.mode === 'markers')
               .map(t => ({name: t.name, x: t.x[0], y: t.y[0]})))"""
        )
    }
    assert markers["target"] == {"name": "target", "x": 250, "y": summary["depth_m"]}
    assert markers["target, 1 px"]["y"] == summary["depth_resolution_m"]
    assert markers["target, 0.25 px"]["y"] == summary["depth_resolution_subpx_m"]
    assert p.locator("#chart-depth .annotation-text").text_content() == "Z = 1.286 m"

    # The inverse question, answered by the library.
    required = StereoRig(150, 6, 2.8).required_baseline_mm(2, 0.005, 0.25)
    assert page.value("required_baseline_mm") == f"{required:.6g}"
    page.screenshot("web-page.png")


BAD = [
    ("baseline_mm", "-5", "Baseline B must be a number > 0 and <= 1000000, got -5"),
    ("baseline_mm", "abc", "Baseline B must be a number > 0 and <= 1000000, got 'abc'"),
    ("baseline_mm", "", "Baseline B is required"),
    ("focal_mm", "0", "Focal length f must be a number > 0 and <= 10000, got 0"),
    ("pixel_um", "NaN", "Pixel size p must be a number > 0 and <= 1000, got NaN"),
    ("width_px", "1e300", "Image width W must be an integer >= 1 and <= 1000000, got 1e300"),
    # d >= -doffs is the rig's rule (the library's message): without doffs, d >= 0
    ("disparity_px", "-1", "Disparity d must be finite and >= 0, got -1.0"),
    (
        "disparity_step_px",
        "1e999",
        "Sub-pixel accuracy Δd must be a number > 0 and <= 1000, got 1e999",
    ),
    ("inverse_depth_m", "", "At depth Z is required with depth error ΔZ"),
]


@pytest.mark.browser
def test_bad_input_shows_a_message_at_its_field_and_keeps_the_results(page: Page) -> None:
    p = page.page
    page.fill(ARM)
    page.expect(p.locator("#out-depth_m .value")).to_have_text("1.28571")
    before = p.locator("#depth-table tbody").inner_html()
    for name, text, message in BAD:
        good = p.input_value(f"#{name}")
        p.fill(f"#{name}", text)
        error = p.locator(f"#{name}-error")
        page.expect(error).to_be_visible()
        page.expect(error).to_have_text(message)
        page.expect(p.locator(f"#{name}")).to_have_attribute("aria-invalid", "true")
        page.expect(p.locator("#status")).to_contain_text("showing the last valid results")
        assert page.value("depth_m") == "1.28571"  # the last good results stay
        assert p.locator("#depth-table tbody").inner_html() == before
        if name == "baseline_mm" and text == "-5":
            page.screenshot("web-page-error.png")
        p.fill(f"#{name}", good)
        page.expect(error).to_be_hidden()
        page.expect(p.locator("#status")).to_have_text("Up to date.")
    assert p.locator(".field.invalid").count() == 0


@pytest.mark.browser
def test_an_empty_focal_length_in_pixels_is_marked_at_its_input(page: Page, tmp_path: Path) -> None:
    # Focal length given in pixels, its input left empty: the page said "Check the marked
    # input" and marked none; its message asked for focal_mm and pixel_um, inputs this mode
    # hides (the API, which has no modes, asks for those). In the depth view too.
    p = page.page
    p.check('input[name="focal_mode"][value="px"]')
    p.fill("#focal_px", "")
    error = p.locator("#focal_px-error")
    page.expect(error).to_have_text("Focal length f/p is required")
    page.expect(p.locator("#focal_px")).to_have_attribute("aria-invalid", "true")
    page.expect(p.locator("#status")).to_have_text(
        "Check the marked input; showing the last valid results."
    )
    from PIL import Image

    for name in ("left", "right"):
        Image.new("L", (64, 48), 90).save(tmp_path / f"{name}.png")
        p.set_input_files(f"#{name}-file", str(tmp_path / f"{name}.png"))
    p.click("#tab-depth")
    p.click("#run-depth")
    page.expect(p.locator("#depth-status")).to_have_text(
        "Not computed. Check the marked inputs (the rig is on the left)."
    )
    page.expect(error).to_have_text("Focal length f/p is required")
    p.click("#tab-calc")
    p.fill("#focal_px", "700")
    page.expect(error).to_be_hidden()
    page.expect(p.locator("#status")).to_have_text("Up to date.")


@pytest.mark.browser
def test_focal_length_in_pixels_and_use_this_baseline(page: Page) -> None:
    p = page.page
    page.fill(ARM)
    page.expect(p.locator("#out-depth_m .value")).to_have_text("1.28571")
    p.check('input[name="focal_mode"][value="px"]')
    page.expect(p.locator("#focal_px")).to_be_visible()
    page.expect(p.locator("#focal_mm")).to_be_hidden()
    assert float(p.input_value("#focal_px")) == StereoRig(150, 6, 2.8).focal_px
    page.expect(p.locator("#status")).to_have_text("Up to date.")
    assert page.value("depth_m") == "1.28571"
    assert page.value("disparity_mm") == "—"  # needs the pixel size

    p.fill("#focal_px", "1000")
    page.expect(p.locator("#out-depth_m .value")).to_have_text(
        f"{StereoRig.from_pixels(150, 1000).depth_m(250):.6g}"
    )
    p.click("#use-baseline")
    required = StereoRig.from_pixels(150, 1000).required_baseline_mm(2, 0.005, 0.25)
    page.expect(p.locator("#baseline_mm")).to_have_value(f"{required:.6g}")
    page.expect(p.locator("#status")).to_have_text("Up to date.")
    got = StereoRig.from_pixels(float(f"{required:.6g}"), 1000).depth_resolution_m(2, 0.25)
    assert got == pytest.approx(0.005, rel=1e-5)


@pytest.mark.browser
@pytest.mark.parametrize("disparity", ["-50", "0"])
def test_a_target_off_the_log_axis_is_not_drawn_there(page: Page, disparity: str) -> None:
    # With doffs > 0 a disparity of 0 or below (down to -doffs) has a finite depth, and
    # chart_data marks it on the depth chart at that disparity, which a log axis cannot
    # show. The page drew the red target where the last target had been (d = 250 px, Z = 0.3
    # m) and its label "Z = 2.1 m" over the axis title, with SVG errors in the console;
    # `stereodepth calc --plot` leaves it out, and so does the page now.
    p = page.page
    p.check('input[name="focal_mode"][value="px"]')
    page.fill({"baseline_mm": "150", "focal_px": "700", "doffs_px": "100"})
    page.expect(p.locator("#out-depth_m .value")).to_have_text("0.3")  # d = 250 px
    p.wait_for_function(
        "() => (document.getElementById('chart-depth').layout || {}).annotations?.length === 1"
    )
    p.fill("#disparity_px", disparity)
    depth = StereoRig.from_pixels(150, 700, doffs_px=100).depth_m(float(disparity))
    page.expect(p.locator("#out-depth_m .value")).to_have_text(f"{depth:.6g}")
    page.expect(p.locator("#status")).to_have_text("Up to date.")
    drawn = (
        "id => { const g = document.getElementById(id); return g.layout.annotations.length === "
        "%d && g.data.length === %d ? [g.data.map(t => t.name), g.layout.annotations.map(a => "
        "a.text), (g.layout.shapes || []).length] : null; }"
    )
    depth_chart = p.wait_for_function(drawn % (0, 1), arg="chart-depth").json_value()
    assert depth_chart == [["depth"], [], 0]
    error_chart = p.wait_for_function(drawn % (2, 4), arg="chart-error").json_value()
    assert error_chart[1] == [
        f"ΔZ = {depth * depth / 105:.4g} m (1 px)",
        f"ΔZ = {depth * depth * 0.25 / 105:.4g} m (0.25 px)",
    ]


@pytest.mark.browser
def test_page_digits_are_printfs(page: Page) -> None:
    values = [
        1.2857142857142856,
        0.005142857142857143,
        321.4285714285714,
        2142.8571428571427,
        0.7,
        1e-5,
        9.9999951e-5,
        999999.5,
        1234567.8,
        0.1,
        100.0,
        2.5e-10,
        1e21,
        123456789.0,
        0.00012345678,
        33.25826391851462,
        7.0,
        5e-324,
        1.7976931348623157e308,
    ]
    got = page.page.evaluate("vs => vs.map(v => window.stereodepth.formatG(v))", values)
    assert got == [f"{v:.6g}" for v in values]


@pytest.mark.browser
def test_page_digits_round_a_tie_to_even_as_printf(page: Page) -> None:
    # JavaScript's toExponential rounds a value exactly halfway between two decimals away from
    # zero, printf (and Python) to the even digit: the page showed a focal length of 1000.125
    # px as 1000.13 where `stereodepth calc` prints 1000.12, a colour bar's 2.0625 m as 2.063
    # (2.062), and a value that rounds past the largest double made formatG throw.
    values = [1000.125, 1234565.0, 412462500.0, 2.0625, 12.125, 0.125, 532.5, 999999.5]
    values += [0.0625, -2.0625, 1.0000005, 131.25, 3.5, 4.5, 1.7976931348623157e308]
    for digits in (6, 4, 3, 2):
        got = page.page.evaluate(
            "([vs, d]) => vs.map(v => window.stereodepth.formatG(v, d))", [values, digits]
        )
        assert got == [f"{v:.{digits}g}" for v in values], digits
    p = page.page
    p.check('input[name="focal_mode"][value="px"]')
    page.fill({"focal_px": "1000.125", "doffs_px": ""})
    page.expect(p.locator("#out-focal_px .value")).to_have_text("1000.12")
    cli = cli_text("--baseline-mm", "150", "--focal-px", "1000.125")
    assert cli_value(cli, "focal length") == "1000.12"


@pytest.mark.browser
def test_readout_digits_are_numpys_repr_of_the_float32(page: Page) -> None:
    # The readout's shortest decimal that reads back as the float32: where two of that length
    # are equally near (the value exactly halfway), numpy takes the even one; the page took the
    # one away from zero (a disparity of 233.015625 px read 233.01563, numpy 233.01562).
    import numpy as np

    rng = np.random.default_rng(7)
    ties = [233.015625, 233.046875, 6340.78125, 0.000244140625, 3282233.25, 195255.625]
    samples = rng.uniform(0.01, 500, 2000).astype(np.float32)
    values = np.concatenate([np.float32(ties), samples, np.float32([1, 0.5, 12.5, 0.1])])
    got = page.page.evaluate(
        "vs => vs.map(v => window.stereodepthDepth.f32(v))", [float(v) for v in values]
    )
    assert got == [_f32_text(v) for v in values]


# --- the depth-map view --------------------------------------------------------------------------
def _hover(p: Any, selector: str, x: int, y: int, width: int, height: int) -> tuple[int, int]:
    """Moves the mouse to a whole CSS pixel inside image pixel (x, y) of the drawn map and
    returns the pixel the page computes there (Chromium's mouse events are whole CSS pixels)."""
    import math

    p.locator(selector).scroll_into_view_if_needed()
    box = p.locator(selector).bounding_box()
    cx = math.floor(box["x"] + (x + 0.5) * box["width"] / width)
    cy = math.floor(box["y"] + (y + 0.5) * box["height"] / height)
    p.mouse.move(cx, cy)
    # The page's own arithmetic: floor((clientX - left) * W / width).
    return (
        math.floor((cx - box["x"]) * width / box["width"]),
        math.floor((cy - box["y"]) * height / box["height"]),
    )


def _sample_depth_map(page: Any) -> Any:
    """The depth view opened on the sample pair, its depth map drawn; returns the page."""
    p = page.page
    p.click("#tab-depth")
    p.click("#use-sample")
    page.expect(p.locator("#depth-status")).to_contain_text("Done: 320\u00d7240 px", timeout=60_000)
    return p


def _f32_text(v: float) -> str:
    import numpy as np

    return np.format_float_positional(np.float32(v), unique=True, trim="-")


def _check_depth_view(
    page: Page,
    disparity: Any,
    depth: Any,
    rig: StereoRig,
    step: float,
    pixels: list[Any],
    centre: tuple[float, float] | None = None,
) -> None:
    """The three maps drawn; under the cursor the library's numbers; pins and the last two's
    distance; the 3-D view drawn."""
    import numpy as np

    from stereodepth import reproject

    p = page.page
    h, w = disparity.shape
    for key in ("left", "disparity", "depth"):
        img = p.locator(f"#img-{key}")
        page.expect(img).to_be_visible()
        size = p.evaluate(
            f"() => {{ const i = document.getElementById('img-{key}');"
            " return [i.complete, i.naturalWidth, i.naturalHeight]; }"
        )
        assert size == [True, w, h], key
    for cb in ("#cb-disparity .bar", "#cb-depth .bar"):
        page.expect(p.locator(cb)).to_be_visible()
    page.expect(p.locator("#cb-depth .ticks")).to_contain_text("m")

    pins = []
    for x0, y0 in pixels:
        x, y = _hover(p, "#img-depth", x0, y0, w, h)
        # Within one CSS pixel of the aim (a CSS pixel spans w / drawn width image pixels).
        reach = 1 + w / p.locator("#img-depth").bounding_box()["width"]
        assert abs(x - x0) <= reach and abs(y - y0) <= reach
        page.expect(p.locator("#ro-x")).to_have_text(str(x))
        page.expect(p.locator("#ro-y")).to_have_text(str(y))
        z = float(depth[y, x])
        assert np.isfinite(z), (x, y)
        # The depth shown is disparity_to_depth's float32, to the last digit.
        assert p.inner_text("#ro-depth") == _f32_text(z)
        assert p.inner_text("#ro-disparity") == _f32_text(float(disparity[y, x]))
        assert p.inner_text("#ro-res1") == f"{rig.depth_resolution_m(z, 1.0):.6g}"
        assert p.inner_text("#ro-resstep") == f"{rig.depth_resolution_m(z, step):.6g}"
        p.mouse.down()
        p.mouse.up()
        pins.append((x, y))
        page.expect(p.locator("#pin-table tbody tr")).to_have_count(len(pins))
    # Two pins: their distance, from reproject's points.
    points = reproject(
        disparity,
        focal_px=rig.focal_px,
        baseline_m=rig.baseline_mm / 1000,
        doffs_px=rig.doffs_px,
        cx_px=centre[0] if centre else None,
        cy_px=centre[1] if centre else None,
    ).astype(np.float64)
    (xa, ya), (xb, yb) = pins[-2:]
    dist = float(np.sqrt(((points[ya, xa] - points[yb, xb]) ** 2).sum()))
    page.expect(p.locator("#distance-value")).to_have_text(f"{dist:.6g}")
    rows = p.locator("#pin-table tbody tr")
    for k, (x, y) in enumerate(pins):
        assert rows.nth(k).locator("td").all_inner_texts()[1:5] == [
            str(x),
            str(y),
            _f32_text(float(disparity[y, x])),
            _f32_text(float(depth[y, x])),
        ]
    # The 3-D view: plotly drew the decimated cloud (WebGL canvas) with the two pins.
    page.expect(p.locator("#cloud .gl-container canvas").first).to_be_attached()
    drawn = p.evaluate("() => document.getElementById('cloud').data.map(t => [t.type, t.x.length])")
    assert drawn[0][0] == "scatter3d" and drawn[0][1] > 1000
    assert drawn[1] == ["scatter3d", len(pins)]  # the pinned points


@pytest.mark.browser
def test_depth_view_sample_pair(page: Page) -> None:
    from stereodepth import block_match, disparity_to_depth
    from stereodepth.sample import sample_pair

    p = page.page
    p.click("#tab-depth")
    page.expect(p.locator("#view-depth")).to_be_visible()
    page.expect(p.locator("#view-calc")).to_be_hidden()
    p.click("#use-sample")
    page.expect(p.locator("#depth-status")).to_contain_text("Done: 320\u00d7240 px", timeout=60_000)
    # The rig is the sample's, in the shared inputs.
    assert p.input_value("#focal_px") == "700" and p.input_value("#baseline_mm") == "120"
    s = sample_pair()
    disparity = block_match(s.left, s.right, num_disparities=48)
    depth = disparity_to_depth(disparity, focal_px=700.0, baseline_m=0.12)
    rig = StereoRig.from_pixels(120, 700)
    # The box (disparity 30), the wall (10) and the disc (20).
    _check_depth_view(page, disparity, depth, rig, 0.25, [(205, 140), (60, 200), (105, 110)])
    page.screenshot("web-depth-sample.png")
    # Back to the calculator: the rig is the one the depth view used.
    p.click("#tab-calc")
    page.expect(p.locator("#out-focal_px .value")).to_have_text("700")


@pytest.mark.browser
def test_depth_view_semi_global_with_the_forms_defaults(page: Page) -> None:
    """Choosing "semi-global" on the page and computing failed whatever else was set: the
    page sent its block-matching fields too (cost census, block size 9), which semi-global
    matching does not take ("cost is an option of method 'bm'"). Now it sends them for
    block matching only, and the result is semi_global_match's."""
    from stereodepth.match_pair import sgm_available

    if not sgm_available():
        pytest.skip("this build has no semi-global matcher")
    import numpy as np

    from stereodepth import semi_global_match
    from stereodepth.sample import sample_pair

    p = page.page
    p.click("#tab-depth")
    p.wait_for_function("() => document.getElementById('limit-text').textContent.includes('MB')")
    p.select_option("#method", "sgm")
    assert p.input_value("#block_size") == "3" and p.is_disabled("#cost")
    p.click("#use-sample")
    page.expect(p.locator("#depth-status")).to_contain_text("Done: 320\u00d7240 px", timeout=60_000)
    s = sample_pair()
    want = semi_global_match(s.left, s.right, num_disparities=48)
    got = p.evaluate("() => Array.from(window.stereodepthDepth.result().disparity)")
    assert len(got) == want.size
    assert np.array_equal(np.asarray(got, np.float32).reshape(want.shape), want, equal_nan=True)


@pytest.mark.browser
def test_depth_view_reads_the_corner_pixels(page: Page) -> None:
    # The maps' frames had rounded corners that clipped the image: the corner pixels were
    # neither drawn nor under the cursor (the readout kept the last pixel read).
    import math

    p = _sample_depth_map(page)
    w, h = 320, 240
    for key in ("left", "disparity", "depth"):
        selector = f"#img-{key}"
        p.locator(selector).scroll_into_view_if_needed()
        box = p.locator(selector).bounding_box()
        left, top = math.ceil(box["x"]), math.ceil(box["y"])
        right = math.ceil(box["x"] + box["width"]) - 1
        bottom = math.ceil(box["y"] + box["height"]) - 1
        for cx, cy in ((left, top), (right, top), (left, bottom), (right, bottom)):
            x, y = _hover(p, selector, w // 2, h // 2, w, h)  # away from the corner first
            page.expect(p.locator("#ro-x")).to_have_text(str(x))
            p.mouse.move(cx, cy)
            x = math.floor((cx - box["x"]) * w / box["width"])
            y = math.floor((cy - box["y"]) * h / box["height"])
            assert (x in (0, 1, w - 2, w - 1)) and (y in (0, 1, h - 2, h - 1))
            page.expect(p.locator("#ro-x")).to_have_text(str(x))
            page.expect(p.locator("#ro-y")).to_have_text(str(y))


@pytest.mark.browser
def test_a_pin_answered_after_a_new_depth_map_is_not_added_to_it(page: Page) -> None:
    # A click pins a pixel of the depth map shown; when the point's answer came back after
    # another depth map had been drawn (a slow answer, a quick second "Compute"), the old
    # map's pixel was pinned on the new one, with the old map's numbers.
    p = _sample_depth_map(page)
    first = p.evaluate("() => window.stereodepthDepth.result().id")
    held: list[Any] = []
    p.route("**/point?*", lambda route: held.append(route))
    _hover(p, "#img-depth", 205, 140, 320, 240)
    p.mouse.down()
    p.mouse.up()
    for _ in range(100):
        if held:
            break
        p.wait_for_timeout(50)
    assert len(held) == 1 and first in held[0].request.url
    p.click("#use-sample")
    p.wait_for_function(f"() => window.stereodepthDepth.result().id !== {first!r}")
    page.expect(p.locator("#depth-status")).to_contain_text("Done: 320\u00d7240 px")
    with p.expect_response("**/point?*"):
        held[0].continue_()
    p.wait_for_timeout(300)  # the page's handler of that answer has run
    assert p.evaluate("() => window.stereodepthDepth.pins().length") == 0
    assert p.locator("#pin-table tbody tr").count() == 0
    # And a pin whose request gets no answer says so, where it threw in the console.
    p.unroute("**/point?*")
    p.route("**/point?*", lambda route: route.abort())
    _hover(p, "#img-depth", 60, 200, 320, 240)
    p.mouse.down()
    p.mouse.up()
    page.expect(p.locator("#depth-status")).to_contain_text("not pinned")
    assert p.evaluate("() => window.stereodepthDepth.pins().length") == 0
    p.unroute("**/point?*")
    page.errors = [e for e in page.errors if "ERR_FAILED" not in e]  # the aborted request


@pytest.mark.browser
@pytest.mark.data
def test_depth_view_shared_scene_with_calib(
    page: Page, tmp_path: Path, stereo_data_dir: Path
) -> None:
    from stereodepth import block_match, disparity_to_depth
    from stereodepth.io import read_image

    scene = stereo_data_dir / "mb2014q-piano"
    if not (scene / "left.png").is_file():
        pytest.skip(f"the shared scene mb2014q-piano is not at {scene}")
    left, right = read_image(scene / "left.png"), read_image(scene / "right.png")
    h, w = left.shape[:2]
    calib = tmp_path / "calib.txt"
    calib.write_text(
        "cam0=[713.189 0 276.193; 0 713.189 242.587; 0 0 1]\ndoffs=31.34\nbaseline=178.089\n"
        f"width={w}\nheight={h}\nndisp=73\n"
    )
    p = page.page
    p.click("#tab-depth")
    p.set_input_files("#calib-file", str(calib))
    page.expect(p.locator("#calib-note")).to_contain_text("f = 713.189 px")
    assert p.input_value("#num_disparities") == "73" and p.input_value("#doffs_px") == "31.34"
    p.set_input_files("#left-file", str(scene / "left.png"))
    p.set_input_files("#right-file", str(scene / "right.png"))
    p.click("#run-depth")
    page.expect(p.locator("#depth-status")).to_contain_text(
        f"Done: {w}\u00d7{h} px", timeout=60_000
    )
    disparity = block_match(left, right, num_disparities=73)
    depth = disparity_to_depth(disparity, focal_px=713.189, baseline_m=0.178089, doffs_px=31.34)
    rig = StereoRig.from_pixels(178.089, 713.189, doffs_px=31.34)
    # The 3-D points use the calib.txt's principal point (cam0's cx, cy).
    _check_depth_view(
        page, disparity, depth, rig, 0.25, [(400, 300), (200, 400)], (276.193, 242.587)
    )
    page.screenshot("web-depth-piano.png")


@pytest.mark.browser
def test_depth_view_bad_upload_shows_a_message_at_the_field(page: Page, tmp_path: Path) -> None:
    p = page.page
    p.click("#tab-depth")
    not_image = tmp_path / "notes.png"
    not_image.write_text("not an image")
    from PIL import Image

    Image.new("RGB", (64, 48)).save(tmp_path / "right.png")
    p.set_input_files("#left-file", str(not_image))
    p.set_input_files("#right-file", str(tmp_path / "right.png"))
    p.click("#run-depth")
    error = p.locator("#left-error")
    page.expect(error).to_be_visible()
    page.expect(error).to_have_text(
        "left: not an image Pillow can read; give a PNG or JPEG file, got 12 bytes of text "
        "beginning 'not an image'"
    )
    page.expect(p.locator("#depth-status")).to_contain_text("Not computed")
    page.expect(p.locator("#right-error")).to_be_hidden()
    # A bad rig value is shown at the rig's input.
    p.fill("#baseline_mm", "-3")
    p.set_input_files("#left-file", str(tmp_path / "right.png"))
    p.click("#run-depth")
    page.expect(p.locator("#baseline_mm-error")).to_contain_text("must be a number > 0")
    page.screenshot("web-depth-error.png")


@pytest.mark.browser
def test_depth_view_refuses_a_calib_of_another_size(page: Page, tmp_path: Path) -> None:
    # The calib.txt of the full-size images with a half-size pair would scale every depth.
    import numpy as np
    from PIL import Image

    rng = np.random.default_rng(5)
    texture = rng.integers(0, 256, (48, 72), dtype=np.uint8)
    Image.fromarray(texture[:, 8:]).save(tmp_path / "left.png")
    Image.fromarray(texture[:, :64]).save(tmp_path / "right.png")
    calib = tmp_path / "calib.txt"
    calib.write_text(
        "cam0=[100 0 63.5; 0 100 47.5; 0 0 1]\ndoffs=0\nbaseline=120\nwidth=128\nheight=96\n"
    )
    p = page.page
    p.click("#tab-depth")
    p.set_input_files("#calib-file", str(calib))
    page.expect(p.locator("#calib-note")).to_contain_text("f = 100 px")
    p.set_input_files("#left-file", str(tmp_path / "left.png"))
    p.set_input_files("#right-file", str(tmp_path / "right.png"))
    p.click("#run-depth")
    error = p.locator("#calib-error")
    page.expect(error).to_be_visible()
    page.expect(error).to_contain_text(
        "calib: the calib.txt is for 128\u00d796 px images, the pair is 64\u00d748 px"
    )
    page.expect(p.locator("#depth-status")).to_contain_text("Not computed")


def _calib_and_pair(tmp_path: Path, calib_size: tuple[int, int]) -> Path:
    """A 64x48 px pair in tmp_path, and a calib.txt of calib_size with its principal point at
    (10, 20), far from the pair's centre (31.5, 23.5)."""
    import numpy as np
    from PIL import Image

    texture = np.random.default_rng(5).integers(0, 256, (48, 72), dtype=np.uint8)
    Image.fromarray(texture[:, 8:]).save(tmp_path / "left.png")
    Image.fromarray(texture[:, :64]).save(tmp_path / "right.png")
    calib = tmp_path / "calib.txt"
    calib.write_text(
        "cam0=[100 0 10; 0 100 20; 0 0 1]\ndoffs=0\nbaseline=120\n"
        f"width={calib_size[0]}\nheight={calib_size[1]}\n"
    )
    return calib


@pytest.mark.browser
@pytest.mark.parametrize("calib_size", [(128, 96), (64, 48)], ids=["other-size", "pair-size"])
@pytest.mark.parametrize("how", ["removed", "bad-file"])
def test_depth_view_drops_a_calib_removed_or_not_loaded(
    page: Page, tmp_path: Path, how: str, calib_size: tuple[int, int]
) -> None:
    # The calib.txt's principal point and image size were sent after the file was removed
    # (the chooser's Cancel empties it) or another failed to load, its note still shown: a
    # pair of another size was refused as "the calib.txt is for 128x96 px images", one of its
    # size had its 3-D points about the old principal point.
    calib = _calib_and_pair(tmp_path, calib_size)
    p = page.page
    p.click("#tab-depth")
    p.set_input_files("#calib-file", str(calib))
    page.expect(p.locator("#calib-note")).to_contain_text("Rig from calib.txt: f = 100 px")
    if how == "removed":
        p.set_input_files("#calib-file", [])
        page.expect(p.locator("#calib-note")).to_have_text(
            "No calibration: calib.txt removed; its principal point and image size are no "
            "longer used (the rig inputs stay as they are)."
        )
        page.expect(p.locator("#calib-error")).to_be_hidden()
    else:
        bad = tmp_path / "notes.txt"
        bad.write_text("hello\n")
        p.set_input_files("#calib-file", str(bad))
        page.expect(p.locator("#calib-error")).to_have_text(
            "calib: calib.txt: line 1 of a Middlebury calib.txt must be key=value, got 'hello'"
        )
        page.expect(p.locator("#calib-note")).to_have_text(
            "No calibration: notes.txt was not loaded; calib.txt is no longer used (the rig "
            "inputs stay as they are)."
        )
    # The rig inputs keep the numbers the file set, as typed ones.
    assert p.input_value("#focal_px") == "100" and p.input_value("#baseline_mm") == "120"
    p.set_input_files("#left-file", str(tmp_path / "left.png"))
    p.set_input_files("#right-file", str(tmp_path / "right.png"))
    p.click("#run-depth")
    page.expect(p.locator("#depth-status")).to_contain_text("Done: 64\u00d748 px")
    rig = p.evaluate("() => window.stereodepthDepth.result().rig")
    assert (rig["cx_px"], rig["cy_px"]) == (31.5, 23.5)  # the image centre
    assert (rig["focal_px"], rig["baseline_mm"]) == (100, 120)
    # Removing it again, or once more, leaves the page as it starts.
    p.set_input_files("#calib-file", [])
    page.expect(p.locator("#calib-note")).to_have_text("Middlebury calib.txt")


@pytest.mark.browser
def test_depth_view_an_empty_or_pfm_upload_is_named_at_its_field(
    page: Page, tmp_path: Path
) -> None:
    # Two empty files: "right: the same file as left"; a PFM: "got PPM".
    (tmp_path / "empty-left.png").write_bytes(b"")
    (tmp_path / "empty-right.png").write_bytes(b"")
    pfm = b"Pf\n64 48\n-1.0\n" + bytes(4 * 64 * 48)
    (tmp_path / "disparity.pfm").write_bytes(pfm)
    _calib_and_pair(tmp_path, (64, 48))  # the pair's right.png
    p = page.page
    p.click("#tab-depth")
    p.set_input_files("#left-file", str(tmp_path / "empty-left.png"))
    p.set_input_files("#right-file", str(tmp_path / "empty-right.png"))
    p.click("#run-depth")
    for name in ("left", "right"):
        page.expect(p.locator(f"#{name}-error")).to_have_text(
            f"{name}: the file is empty (0 bytes); choose an image file"
        )
    page.expect(p.locator("#depth-status")).to_contain_text("Not computed")
    p.set_input_files("#left-file", str(tmp_path / "disparity.pfm"))
    p.set_input_files("#right-file", str(tmp_path / "right.png"))
    p.click("#run-depth")
    page.expect(p.locator("#left-error")).to_have_text(
        f"left: must be a PNG or JPEG image, got PFM (64x48 px, {len(pfm)} bytes): PFM "
        "holds floating-point maps, such as the disparity.pfm this page and `stereodepth "
        "match` write, not an image to match"
    )
    page.expect(p.locator("#right-error")).to_be_hidden()
