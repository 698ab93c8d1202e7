"""The web calculator's JSON API through FastAPI's test client: the same numbers as the library
and the CLI, every kind of bad input answered 422 at its parameter, never 500."""

from __future__ import annotations

import json
import re
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("fastapi", reason="the web extra is not installed")

from fastapi.testclient import TestClient

from stereodepth import StereoRig
from stereodepth.charts import chart_data
from stereodepth.cli import main
from stereodepth.web.app import FIELDS, Summary, create_app

#: The test client's address: the app answers only a Host that names this machine (DNS
#: rebinding), and the client's default, "testserver", does not.
LOCAL = "http://localhost"

ARM: dict[str, Any] = {"baseline_mm": 150, "focal_mm": 6, "pixel_um": 2.8, "width_px": 1280}
CAR: dict[str, Any] = {"baseline_mm": 250, "focal_mm": 12, "pixel_um": 4.2, "width_px": 2048}


@pytest.fixture(scope="module")
def client() -> TestClient:
    return TestClient(create_app(), base_url=LOCAL)


def calc(client: TestClient, **params: Any) -> Any:
    return client.get("/api/calc", params=params)


def cli_json(capsys: pytest.CaptureFixture[str], *args: str) -> Any:
    assert main(["calc", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def cli_args(params: dict[str, Any]) -> list[str]:
    """The CLI options of API parameters (disparity_step_px is --subpixel-px there)."""
    out: list[str] = []
    for k, v in params.items():
        if k.startswith("inverse_"):
            continue
        flag = "--subpixel-px" if k == "disparity_step_px" else "--" + k.replace("_", "-")
        out += [flag, *map(str, v)] if isinstance(v, list) else [flag, str(v)]
    return out


# --- the same numbers as Python and the CLI -----------------------------------------------------
CASES = [
    pytest.param({**ARM, "disparity_px": 250}, id="arm"),
    pytest.param(
        {**CAR, "disparity_px": 35, "disparity_step_px": 0.25, "max_disparity_px": 192},
        id="car-subpixel-range",
    ),
    pytest.param(
        {
            "baseline_mm": 193.001,
            "focal_px": 3979.911,
            "doffs_px": 124.343,
            "width_px": 2964,
            "height_px": 1988,
            "disparity_px": 0,
        },
        id="middlebury-px",
    ),
    pytest.param(
        {
            **ARM,
            "disparity_px": 0.5,
            "disparity_step_px": 0.1,
            "table_disparities_px": [0, 0.5, 7, 1023],
        },
        id="own-table-infinity",
    ),
    pytest.param({"baseline_mm": 120, "focal_mm": 4, "pixel_um": 3}, id="no-target"),
]


def _rig(params: dict[str, Any]) -> StereoRig:
    if "focal_px" in params:
        return StereoRig.from_pixels(
            params["baseline_mm"],
            params["focal_px"],
            width_px=params.get("width_px"),
            doffs_px=params.get("doffs_px", 0.0),
            height_px=params.get("height_px"),
        )
    return StereoRig(
        params["baseline_mm"],
        params["focal_mm"],
        params["pixel_um"],
        width_px=params.get("width_px"),
        height_px=params.get("height_px"),
    )


def _summary(params: dict[str, Any]) -> dict[str, Any]:
    return _rig(params).summary(
        params.get("disparity_px"),
        disparity_step_px=params.get("disparity_step_px", 1.0),
        max_disparity_px=params.get("max_disparity_px"),
        table_disparities_px=params.get("table_disparities_px"),
    )


@pytest.mark.parametrize("params", CASES)
def test_summary_equals_the_library_and_the_cli(
    client: TestClient, capsys: pytest.CaptureFixture[str], params: dict[str, Any]
) -> None:
    r = calc(client, **params)
    assert r.status_code == 200, r.text
    got = r.json()["summary"]
    # Exactly equal after the JSON round trip: every float to the last bit.
    assert got == json.loads(json.dumps(_summary(params)))
    assert got == cli_json(capsys, *cli_args(params))


def test_worked_examples(client: TestClient) -> None:
    arm = calc(client, **ARM, disparity_px=250).json()["summary"]
    assert round(arm["depth_m"], 2) == 1.29
    assert arm["disparity_mm"] == pytest.approx(0.7, rel=1e-12)
    car = calc(client, **CAR, disparity_px=35).json()["summary"]
    assert round(car["depth_m"], 2) == 20.41
    assert car["disparity_mm"] == pytest.approx(0.147, rel=1e-12)


@pytest.mark.parametrize("params", CASES)
def test_charts_are_the_libraries_chart_data(client: TestClient, params: dict[str, Any]) -> None:
    body = calc(client, **params).json()
    expected = chart_data(
        _rig(params),
        disparity_px=params.get("disparity_px"),
        disparity_step_px=params.get("disparity_step_px", 1.0),
        max_disparity_px=params.get("max_disparity_px"),
    ).to_dict()
    assert body["charts"] == json.loads(json.dumps(expected))
    s = body["summary"]
    markers = {m["name"]: m for c in body["charts"].values() for m in c["markers"]}
    if s["depth_m"] is None:
        assert not markers
    else:
        assert markers["target"] == {"name": "target", "x": s["disparity_px"], "y": s["depth_m"]}
        assert markers["target, 1 px"]["y"] == s["depth_resolution_m"]


# --- the inverse question -----------------------------------------------------------------------
def test_inverse_gives_the_libraries_baseline_and_that_baseline_gives_the_error(
    client: TestClient,
) -> None:
    body = calc(
        client,
        **ARM,
        disparity_px=250,
        disparity_step_px=0.25,
        inverse_depth_m=2,
        inverse_depth_resolution_m=0.005,
    ).json()
    inv = body["inverse"]
    rig = StereoRig(**ARM)
    assert inv["required_baseline_mm"] == rig.required_baseline_mm(2, 0.005, 0.25)
    assert inv == {
        "depth_m": 2,
        "depth_resolution_m": 0.005,
        "disparity_step_px": 0.25,
        "focal_px": rig.focal_px,
        "required_baseline_mm": inv["required_baseline_mm"],
    }
    better = StereoRig(inv["required_baseline_mm"], 6, 2.8)
    assert better.depth_resolution_m(2.0, 0.25) == pytest.approx(0.005, rel=1e-12)
    assert calc(client, **ARM).json()["inverse"] is None


@pytest.mark.parametrize(
    ("given_", "missing"),
    [
        ({"inverse_depth_m": 2}, "inverse_depth_resolution_m"),
        ({"inverse_depth_resolution_m": 0.01}, "inverse_depth_m"),
    ],
)
def test_inverse_needs_both_values(
    client: TestClient, given_: dict[str, float], missing: str
) -> None:
    r = calc(client, **ARM, **given_)
    assert r.status_code == 422
    assert r.json()["detail"] == [
        {
            "loc": ["query", missing],
            "type": "missing",
            "msg": f"{missing} is required with {next(iter(given_))}",
        }
    ]


# --- bad input: 422 at the parameter, with the rule and what was received --------------------
BAD = {
    "empty": "",
    "text": "abc",
    "negative": "-3",
    "zero": "0",
    "huge": "1e300",
    "overflow": "1e999",
    "nan": "NaN",
    "inf": "inf",
}
# Zero is allowed for the disparity (a point at infinity); every other parameter is > 0.
CHECKED = [
    "baseline_mm",
    "focal_mm",
    "pixel_um",
    "width_px",
    "disparity_px",
    "disparity_step_px",
    "max_disparity_px",
    "inverse_depth_m",
    "inverse_depth_resolution_m",
]


def _bad_cases() -> list[Any]:
    cases = []
    for name in CHECKED:
        for kind, text in BAD.items():
            if kind in ("zero", "negative") and name == "disparity_px":
                continue  # the rig's rule (d >= -doffs), tested below with the library's
            cases.append(pytest.param(name, text, id=f"{name}-{kind}"))
    return cases


@pytest.mark.parametrize(("name", "text"), _bad_cases())
def test_bad_value_answers_422_naming_the_parameter(
    client: TestClient, name: str, text: str
) -> None:
    params: dict[str, Any] = {
        **ARM,
        "disparity_px": 250,
        "inverse_depth_m": 2,
        "inverse_depth_resolution_m": 0.005,
    }
    params[name] = text
    r = calc(client, **params)
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["loc"] == ["query", name]
    rule = FIELDS[name].rule
    shown = "an empty value" if text == "" else repr(text) if text == "abc" else text
    assert err["msg"] == f"{name} must be {rule}, got {shown}"


def test_rule_matches_the_schema_range() -> None:
    assert FIELDS["baseline_mm"].rule == "a number > 0 and <= 1000000"
    assert FIELDS["width_px"].rule == "an integer >= 1 and <= 1000000"
    assert FIELDS["disparity_px"].rule == "a number <= 1000000"  # d >= -doffs: the rig's rule


@pytest.mark.parametrize(
    ("params", "loc", "msg"),
    [
        pytest.param(
            {"focal_mm": 6, "pixel_um": 2.8},
            "baseline_mm",
            "baseline_mm is required",
            id="no-baseline",
        ),
        pytest.param(
            {"baseline_mm": 150, "pixel_um": 2.8},
            "focal_mm",
            "focal_mm is required (or give focal_px)",
            id="no-focal",
        ),
        pytest.param(
            {"baseline_mm": 150, "focal_mm": 6, "pixel_um": 2.8, "focal_px": 2000},
            "focal_mm",
            "give either focal_px, or focal_mm and pixel_um, not both (got focal_px and focal_mm)",
            id="both-focals",
        ),
        pytest.param(
            {**ARM, "doffs_px": 3},
            "doffs_px",
            "doffs_px goes with focal_px (a calibration in pixels), got doffs_px 3 with focal_mm "
            "and pixel_um",
            id="doffs-with-mm",
        ),
        pytest.param(  # was "... with focal_mm and pixel_um": neither was given
            {"baseline_mm": 150, "doffs_px": 3},
            "doffs_px",
            "doffs_px goes with focal_px (a calibration in pixels), got doffs_px 3 without "
            "focal_px",
            id="doffs-without-focal",
        ),
        pytest.param(  # was "... with focal_mm and pixel_um": pixel_um was not given
            {"baseline_mm": 150, "focal_mm": 6, "doffs_px": 3},
            "doffs_px",
            "doffs_px goes with focal_px (a calibration in pixels), got doffs_px 3 with focal_mm",
            id="doffs-with-focal-mm",
        ),
        pytest.param(
            {"baseline_mm": 150, "focal_px": 2000, "doffs_px": -0.5, "disparity_px": 0.2},
            "disparity_px",
            "disparity_px must be finite and >= 0.5 (with doffs_px -0.5, a disparity below 0.5 px "
            "puts the point behind the cameras), got 0.2",
            id="library-rule-doffs",
        ),
        pytest.param(  # no doffs: a negative disparity is behind the cameras
            {**ARM, "disparity_px": -3},
            "disparity_px",
            "disparity_px must be finite and >= 0, got -3.0",
            id="negative-disparity",
        ),
        pytest.param(  # below -doffs: behind the cameras
            {"baseline_mm": 176.252, "focal_px": 1038.018, "doffs_px": 53.271, "disparity_px": -54},
            "disparity_px",
            "disparity_px must be finite and >= -53.271 (with doffs_px 53.271, a disparity of "
            "-53.271 px is a point at infinity and one below it lies behind the cameras), got "
            "-54.0",
            id="library-rule-positive-doffs",
        ),
        pytest.param(
            {**ARM, "width_px": "1280.5"},
            "width_px",
            "width_px must be an integer >= 1 and <= 1000000, got 1280.5",
            id="fraction",
        ),
        pytest.param(  # was "... at most 1000 values", without how many came
            {**ARM, "table_disparities_px": list(range(1, 1002))},
            "table_disparities_px",
            "table_disparities_px takes at most 1000 values, got 1001",
            id="table-too-long",
        ),
        pytest.param(  # was at ["query"], at no parameter
            {"baseline_mm": 1e-300, "focal_px": 1e-300},
            "baseline_mm",
            "baseline_mm=1e-300 with a focal length of 1e-300 px gives B*f = 0.0 m*px, outside "
            "the range of a double",
            id="library-name-equals",
        ),
    ],
)
def test_rules_across_parameters(
    client: TestClient, params: dict[str, Any], loc: str, msg: str
) -> None:
    r = calc(client, **params)
    assert r.status_code == 422, r.text
    assert {"loc": ["query", loc], "msg": msg} in [
        {"loc": e["loc"], "msg": e["msg"]} for e in r.json()["detail"]
    ]


def test_negative_disparity_within_doffs_answers_as_the_library(client: TestClient) -> None:
    # Adirondack's rig (doffs 53.271 px): a point 10 m away has disparity -34.97 px, which
    # StereoRig.depth_m and `stereodepth calc` take; the page refused every d < 0.
    rig = StereoRig.from_pixels(baseline_mm=176.252, focal_px=1038.018, doffs_px=53.271)
    d = float(rig.disparity_px(10.0))
    assert d < 0
    r = calc(client, baseline_mm=176.252, focal_px=1038.018, doffs_px=53.271, disparity_px=d)
    assert r.status_code == 200, r.text
    s = r.json()["summary"]
    assert s["depth_m"] == float(rig.depth_m(d))
    assert s["depth_m"] == pytest.approx(10.0, rel=1e-12)


@pytest.mark.parametrize(
    ("params", "loc", "start"),
    [
        pytest.param(
            {"baseline_mm": 1e6, "focal_px": 1e7, "disparity_px": "5e-324"},
            "disparity_px",
            "disparity_px must give a depth (B*f / (d + doffs), B*f = 10000000000.0 m*px) that a "
            "double can hold (it overflows to inf or rounds to 0), got 5e-324, which gives inf m",
            id="depth",
        ),
        pytest.param(
            {**ARM, "inverse_depth_m": 1e6, "inverse_depth_resolution_m": "5e-324"},
            "inverse_depth_m",
            "inverse_depth_m must give a baseline that a double can hold",
            id="inverse",
        ),
    ],
)
def test_results_a_double_cannot_hold_answer_422(
    client: TestClient, params: dict[str, Any], loc: str, start: str
) -> None:
    # They came back null (200), like a value the rig cannot give.
    r = calc(client, **params)
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["loc"] == ["query", loc]
    assert err["msg"].startswith(start)


def test_every_bad_parameter_is_reported_at_once(client: TestClient) -> None:
    r = client.get("/api/calc?baseline_mm=x&focal_mm=-1&pixel_um=nan&width_px=0")
    assert r.status_code == 422
    assert [e["loc"][1] for e in r.json()["detail"]] == [
        "baseline_mm",
        "focal_mm",
        "pixel_um",
        "width_px",
    ]


def test_bad_table_value_is_located(client: TestClient) -> None:
    r = client.get(
        "/api/calc?baseline_mm=1&focal_px=10&table_disparities_px=2&table_disparities_px=-1"
    )
    assert r.status_code == 422
    (err,) = r.json()["detail"]
    assert err["loc"] == ["query", "table_disparities_px", 1]
    assert err["msg"] == "table_disparities_px[1] must be a number >= 0 and <= 1000000, got -1"


_value = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(min_value=1e-300, max_value=1e6).map(repr),
    st.integers(min_value=-(10**30), max_value=10**30).map(str),
    st.sampled_from(["", " ", "nan", "-inf", "1e999", "5e-324", "0x10", "1,5", "١٢", "1_0"]),
    st.text(max_size=8),
)


@settings(max_examples=300, deadline=None)
@given(
    params=st.dictionaries(st.sampled_from(sorted(FIELDS)), _value, max_size=8),
    base=st.sampled_from([ARM, {"baseline_mm": 1, "focal_px": 10}, {}]),
)
def test_no_input_answers_500(
    client: TestClient, params: dict[str, str], base: dict[str, Any]
) -> None:
    r = calc(client, **{**base, **params})
    assert r.status_code in (200, 422), r.text
    body = r.json()  # valid JSON: no NaN or inf
    if r.status_code == 422:
        for err in body["detail"]:
            assert err["loc"][0] == "query"
            if len(err["loc"]) > 1:
                assert err["msg"].startswith(err["loc"][1]) or "focal_px" in err["msg"]
    else:
        assert set(body) == {"summary", "inverse", "charts"}


# --- the schema, the page and its files ----------------------------------------------------------
def test_openapi_schema_describes_the_api(client: TestClient) -> None:
    schema = client.get("/openapi.json").json()
    op = schema["paths"]["/api/calc"]["get"]
    assert {p["name"] for p in op["parameters"]} == set(FIELDS)
    by_name = {p["name"]: p for p in op["parameters"]}
    assert by_name["baseline_mm"]["required"] is True
    assert by_name["baseline_mm"]["schema"]["exclusiveMinimum"] == 0
    assert by_name["baseline_mm"]["schema"]["maximum"] == FIELDS["baseline_mm"].maximum
    assert "(mm)" in by_name["baseline_mm"]["description"]
    assert set(op["responses"]) >= {"200", "422"}
    # The documented response lists exactly the keys StereoRig.summary() returns.
    keys = set(StereoRig(**ARM).summary(250, max_disparity_px=64))
    assert set(Summary.model_fields) == keys
    props = schema["components"]["schemas"]["Summary"]["properties"]
    assert set(props) == keys


def test_fields_list_units_and_ranges(client: TestClient) -> None:
    body = client.get("/api/fields").json()
    assert body["version"]
    fields = {f["name"]: f for f in body["fields"]}
    assert set(fields) == set(FIELDS)
    assert fields["pixel_um"]["unit"] == "µm"
    assert fields["baseline_mm"]["rule"] == FIELDS["baseline_mm"].rule


def test_page_and_its_files_are_served_from_here(client: TestClient) -> None:
    page = client.get("/")
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    assert "default-src 'self'" in page.headers["content-security-policy"]
    refs = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert "/vendor/plotly.min.js" in refs
    for ref in refs:
        assert not ref.startswith(("http:", "https:", "//")), ref  # nothing from the internet
        if ref.startswith("/"):
            r = client.get(ref)
            assert r.status_code == 200, ref
            assert r.content, ref
    js = client.get("/vendor/plotly.min.js")
    assert js.headers["content-type"].startswith("text/javascript")
    assert len(js.content) > 1_000_000 and b"plotly" in js.content[:2000].lower()
    assert client.get("/docs").status_code == 404  # Swagger UI would load from a CDN


@pytest.mark.parametrize(
    ("query", "loc", "msg"),
    [
        (  # a misspelt parameter was ignored: the answer came without the disparity asked for
            "baseline_mm=120&focal_px=700&disparity=30",
            "disparity",
            "disparity is not a parameter of /api/calc, got '30' (its parameters: baseline_mm, ",
        ),
        (  # the same parameter twice: the last one was used without a word
            "baseline_mm=120&focal_px=700&baseline_mm=200",
            "baseline_mm",
            "baseline_mm is given 2 times ('120', '200'): give it once",
        ),
    ],
    ids=["unknown", "twice"],
)
def test_unknown_and_repeated_parameters_are_refused(
    client: TestClient, query: str, loc: str, msg: str
) -> None:
    r = client.get(f"/api/calc?{query}")
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["loc"] == ["query", loc]
    assert err["msg"].startswith(msg), err["msg"]


def test_fields_takes_no_parameters(client: TestClient) -> None:
    # As /api/calc refuses one it does not have; this ignored it.
    r = client.get("/api/fields?name=baseline_mm")
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == [
        {
            "loc": ["query", "name"],
            "msg": "name is not a parameter of /api/fields, got 'baseline_mm' (it takes none)",
            "type": "extra_forbidden",
        }
    ]
    assert client.get("/api/fields").status_code == 200


def test_the_table_disparities_may_repeat(client: TestClient) -> None:
    r = client.get(
        "/api/calc?baseline_mm=120&focal_px=700&table_disparities_px=7&table_disparities_px=14"
    )
    assert r.status_code == 200, r.text
    assert [row["disparity_px"] for row in r.json()["summary"]["table"]] == [7, 14]
