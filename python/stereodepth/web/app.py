"""The web calculator: a FastAPI app serving the page, its static files and a JSON API.

``GET /api/calc`` takes the rig and the question as query parameters, with the names and
units of :class:`~stereodepth.StereoRig` and ``stereodepth calc``, and answers

- ``summary``: exactly ``StereoRig.summary()``, what ``stereodepth calc --json`` prints;
- ``inverse``: the baseline that gives a depth error of ``inverse_depth_resolution_m`` at
  ``inverse_depth_m`` (``StereoRig.required_baseline_mm``), when both are given, else null;
- ``charts``: :func:`stereodepth.charts.chart_data`, what the page draws.

``GET /api/fields`` lists every parameter with its unit and allowed range (the page shows
them), ``/openapi.json`` is the schema. Bad input answers 422 in FastAPI's error shape,
``{"detail": [{"loc": ["query", name], "msg": ..., "type": ...}]}``, whose message names the
parameter, states the rule and shows what was received; no input makes the server answer 500.
A query parameter a route does not have, on any route of the API (``/api/fields`` and the
depth-map view's too), and one given twice where it takes one value, answer 422 at it.
The allowed ranges are the library's rules (e.g. > 0) with a generous upper bound; a value
whose result still leaves the range of a double (a disparity of 5e-324 px, a pixel of 1e-300
µm) answers 422 at that parameter, as the library raises ValueError for it; null means only
"not available" or a true infinity (the depth at disparity 0).

The page works offline: plotly.js is served from the installed ``plotly`` package. The app
answers only requests whose Host header names this server (``create_app``'s
``allowed_hosts``, :mod:`stereodepth.web.host`: 400 at ``["header", "host"]`` for others,
against DNS rebinding), under ``stereodepth serve``, another ASGI server or mounted.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, FastAPI, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel
from pydantic import Field as PydanticField

from .. import __version__
from ..charts import chart_data
from ..rig import StereoRig
from .depthmap import DEFAULT_MAX_PIXELS, DEFAULT_MAX_UPLOAD_BYTES, DepthMapLimits, make_router
from .host import AllowedHosts, HostCheck

__all__ = ["FIELDS", "create_app"]

STATIC_DIR = Path(__file__).resolve().parent / "static"

# Every response: no resources from anywhere but this server (the page works offline).
_SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
        "img-src 'self' data: blob:; connect-src 'self'; object-src 'none'; "
        "base-uri 'none'; frame-ancestors 'none'; form-action 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}


def _number(v: float) -> str:
    """1000000 rather than 1e+06; 0.5 as is."""
    return str(int(v)) if v == int(v) and abs(v) < 1e15 else f"{v:g}"


# --- the parameters ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Field:
    """A query parameter: its unit, meaning and allowed range."""

    name: str
    unit: str
    description: str
    integer: bool = False
    minimum: float | None = 0.0
    exclusive_minimum: bool = True
    maximum: float | None = 1e6

    @property
    def rule(self) -> str:
        """The allowed range in words, e.g. ``a number > 0 and <= 1000000``."""
        kind = "an integer" if self.integer else "a number"
        parts = []
        if self.minimum is not None:
            parts.append(f"{'>' if self.exclusive_minimum else '>='} {_number(self.minimum)}")
        if self.maximum is not None:
            parts.append(f"<= {_number(self.maximum)}")
        return f"{kind} {' and '.join(parts)}".rstrip()

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "unit": self.unit,
            "description": self.description,
            "rule": self.rule,
            "integer": self.integer,
            "minimum": self.minimum,
            "exclusive_minimum": self.exclusive_minimum,
            "maximum": self.maximum,
        }

    def query(self) -> Any:
        """The FastAPI ``Query`` that declares and checks this parameter."""
        description = f"{self.description} ({self.unit}): {self.rule}"
        gt = self.minimum if self.exclusive_minimum else None
        ge = None if self.exclusive_minimum else self.minimum
        if self.integer:
            return Query(description=description, gt=gt, ge=ge, le=self.maximum)
        return Query(description=description, gt=gt, ge=ge, le=self.maximum, allow_inf_nan=False)


_F = [
    Field("baseline_mm", "mm", "baseline B: the distance between the optical centres"),
    Field("focal_mm", "mm", "focal length f of the lenses", maximum=1e4),
    Field("pixel_um", "µm", "pixel size p of the sensor", maximum=1e3),
    Field(
        "focal_px",
        "px",
        "focal length in pixels, f / p (replaces focal_mm and pixel_um)",
        maximum=1e7,
    ),
    Field(
        "doffs_px",
        "px",
        "principal point offset, with focal_px (Middlebury doffs)",
        minimum=-1e6,
        exclusive_minimum=False,
    ),
    Field(
        "width_px",
        "px",
        "image width W, for the horizontal field of view",
        integer=True,
        minimum=1,
        exclusive_minimum=False,
    ),
    Field(
        "height_px",
        "px",
        "image height, for the vertical field of view",
        integer=True,
        minimum=1,
        exclusive_minimum=False,
    ),
    Field(
        # No lower bound here: the rig's rule, d + doffs >= 0 (-doffs is a point at infinity;
        # with doffs > 0 the points beyond B*f / doffs have negative disparities), depends on
        # doffs_px, and the library checks it (422 at disparity_px with its message), as
        # `stereodepth calc` and StereoRig.depth_m take it.
        "disparity_px",
        "px",
        "disparity d of the target (-doffs, 0 for most rigs: infinitely far)",
        minimum=None,
    ),
    Field(
        "disparity_step_px",
        "px",
        "the matcher's disparity accuracy, e.g. 0.25 for sub-pixel; 1 for whole pixels",
        maximum=1e3,
    ),
    Field("max_disparity_px", "px", "top of the disparity search range, for the min depth"),
    Field(
        "table_disparities_px",
        "px",
        "disparities for the table (default 1 to 256 px)",
        exclusive_minimum=False,
    ),
    Field("inverse_depth_m", "m", "the inverse question: at this depth Z ..."),
    Field("inverse_depth_resolution_m", "m", "... which baseline gives this depth error ΔZ?"),
]
#: The parameters of /api/calc by name.
FIELDS: dict[str, Field] = {f.name: f for f in _F}
_TABLE_MAX_ROWS = 1000

# Parameter names in the library's messages that differ from the API's, per call.
_SUMMARY_NAMES = {"disparities_px": "table_disparities_px"}
_INVERSE_NAMES = {"depth_m": "inverse_depth_m", "depth_resolution_m": "inverse_depth_resolution_m"}


# --- the response, for the schema -------------------------------------------------------------
class TableRow(BaseModel):
    disparity_px: float | None
    disparity_mm: float | None = PydanticField(None, description="when the pixel size is known")
    depth_m: float | None
    depth_resolution_m: float | None = PydanticField(description="for a 1 px disparity step")
    depth_resolution_subpx_m: float | None = PydanticField(
        None, description="for disparity_step_px, when it is not 1"
    )


class Summary(BaseModel):
    """StereoRig.summary(): what ``stereodepth calc --json`` prints. Null: not available."""

    focal_px: float
    max_depth_m: float | None
    hfov_deg: float | None
    vfov_deg: float | None
    disparity_px: float | None
    depth_m: float | None
    disparity_mm: float | None
    depth_resolution_m: float | None
    depth_resolution_exact_m: float | None
    disparity_step_px: float
    depth_resolution_subpx_m: float | None
    max_disparity_px: float | None
    min_depth_m: float | None
    table: list[TableRow]


class Inverse(BaseModel):
    """StereoRig.required_baseline_mm(depth_m, depth_resolution_m, disparity_step_px)."""

    depth_m: float
    depth_resolution_m: float
    disparity_step_px: float
    focal_px: float
    required_baseline_mm: float


class SeriesOut(BaseModel):
    name: str
    x: list[float]
    y: list[float]


class MarkerOut(BaseModel):
    name: str
    x: float
    y: float


class ChartOut(BaseModel):
    title: str
    x_label: str
    y_label: str
    x_log: bool
    y_log: bool
    series: list[SeriesOut]
    markers: list[MarkerOut]


class ChartsOut(BaseModel):
    depth_vs_disparity: ChartOut
    error_vs_depth: ChartOut


class CalcResponse(BaseModel):
    summary: Summary
    inverse: Inverse | None
    charts: ChartsOut


class ErrorItem(BaseModel):
    loc: list[str | int]
    msg: str
    type: str


class ErrorResponse(BaseModel):
    detail: list[ErrorItem]


# --- errors -----------------------------------------------------------------------------------
def _error(field: str | None, msg: str, kind: str = "value_error") -> dict[str, Any]:
    return {"loc": ["query", field] if field else ["query"], "msg": msg, "type": kind}


def _unprocessable(errors: list[dict[str, Any]]) -> JSONResponse:
    return JSONResponse(status_code=422, content={"detail": errors})


def _library_error(exc: Exception, names: dict[str, str]) -> dict[str, Any]:
    """The library's message, located at the parameter it names (messages begin with it, as
    ``name ...`` or ``name=value ...``)."""
    msg = str(exc)
    first = msg.split(" ", 1)[0].split("=", 1)[0]
    field = names.get(first, first)
    if field in FIELDS:
        return _error(field, field + msg[len(first) :])
    return _error(None, msg)


def _shown(value: Any) -> str:
    if isinstance(value, str):
        if value.strip() == "":
            return "an empty value"
        try:
            float(value)
        except ValueError:
            return repr(value[:40] + ("..." if len(value) > 40 else ""))
        return value
    return repr(value)


def _request_error(err: dict[str, Any]) -> dict[str, Any]:
    """FastAPI's parse and range errors, reworded in the library's style."""
    loc = [p for p in err.get("loc", ()) if isinstance(p, (str, int))]
    kind = str(err.get("type", "value_error"))
    if kind in ("extra_forbidden", "repeated"):  # known_parameters's, worded already
        return {"loc": loc, "msg": str(err.get("msg")), "type": kind}
    name = loc[1] if len(loc) > 1 and isinstance(loc[1], str) else None
    field = FIELDS.get(name) if name is not None else None
    if field is None:
        # The depth-map view's own parameters (the point query's x and y): pydantic's
        # "Input should be a valid integer, unable to parse string as an integer" named
        # neither the parameter nor what it got.
        if name is not None and kind == "missing":
            return {"loc": loc, "msg": f"{name} is required", "type": kind}
        if name is not None and kind.startswith("int_"):
            msg = f"{name} must be an integer, got {_shown(err.get('input'))}"
            return {"loc": loc, "msg": msg, "type": kind}
        return {"loc": loc, "msg": str(err.get("msg", "invalid input")), "type": kind}
    if kind == "missing":
        msg = f"{field.name} is required"
    elif kind == "too_long":
        given = err.get("input")
        got = f", got {len(given)}" if isinstance(given, (list, tuple)) else ""
        msg = f"{field.name} takes at most {_TABLE_MAX_ROWS} values{got}"
    else:
        label = field.name if len(loc) < 3 else f"{field.name}[{loc[2]}]"
        msg = f"{label} must be {field.rule}, got {_shown(err.get('input'))}"
    return {"loc": loc, "msg": msg, "type": kind}


# --- the calculation --------------------------------------------------------------------------
# What the library raises for input it rejects (ArithmeticError: an overflow it did not catch).
_LIBRARY_ERRORS = (ValueError, TypeError, ArithmeticError)


def _rig(
    baseline_mm: float,
    focal_mm: float | None,
    pixel_um: float | None,
    focal_px: float | None,
    doffs_px: float | None,
    width_px: int | None,
    height_px: int | None,
) -> StereoRig | list[dict[str, Any]]:
    """The rig, or the errors that prevent it (the rules of ``stereodepth calc``)."""
    if focal_px is not None:
        clash = [n for n, v in (("focal_mm", focal_mm), ("pixel_um", pixel_um)) if v is not None]
        if clash:
            return [
                _error(
                    n,
                    f"give either focal_px, or focal_mm and pixel_um, not both "
                    f"(got focal_px and {n})",
                )
                for n in clash
            ]
        return StereoRig.from_pixels(
            baseline_mm,
            focal_px,
            width_px=width_px,
            doffs_px=doffs_px or 0.0,
            height_px=height_px,
        )
    errors = [
        _error(n, f"{n} is required (or give focal_px)", "missing")
        for n, v in (("focal_mm", focal_mm), ("pixel_um", pixel_um))
        if v is None
    ]
    if doffs_px:
        # What came with it: "with focal_mm and pixel_um" was said when neither had come.
        given = [n for n, v in (("focal_mm", focal_mm), ("pixel_um", pixel_um)) if v is not None]
        beside = f"with {' and '.join(given)}" if given else "without focal_px"
        errors.append(
            _error(
                "doffs_px",
                f"doffs_px goes with focal_px (a calibration in pixels), got doffs_px "
                f"{_number(doffs_px)} {beside}",
            )
        )
    if errors or focal_mm is None or pixel_um is None:
        return errors
    return StereoRig(baseline_mm, focal_mm, pixel_um, width_px=width_px, height_px=height_px)


def calculate(
    *,
    baseline_mm: float,
    focal_mm: float | None = None,
    pixel_um: float | None = None,
    focal_px: float | None = None,
    doffs_px: float | None = None,
    width_px: int | None = None,
    height_px: int | None = None,
    disparity_px: float | None = None,
    disparity_step_px: float = 1.0,
    max_disparity_px: float | None = None,
    table_disparities_px: list[float] | None = None,
    inverse_depth_m: float | None = None,
    inverse_depth_resolution_m: float | None = None,
) -> dict[str, Any] | list[dict[str, Any]]:
    """The answer of /api/calc as a dict, or the list of errors (for a 422)."""
    # Extreme but allowed inputs whose results overflow: the library raises ValueError.
    with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
        try:
            rig = _rig(baseline_mm, focal_mm, pixel_um, focal_px, doffs_px, width_px, height_px)
        except _LIBRARY_ERRORS as exc:
            return [_library_error(exc, {})]
        if isinstance(rig, list):
            return rig
        try:
            summary = rig.summary(
                disparity_px,
                disparity_step_px=disparity_step_px,
                max_disparity_px=max_disparity_px,
                table_disparities_px=table_disparities_px,
            )
            charts = chart_data(
                rig,
                disparity_px=disparity_px,
                disparity_step_px=disparity_step_px,
                max_disparity_px=max_disparity_px,
            ).to_dict()
        except _LIBRARY_ERRORS as exc:
            return [_library_error(exc, _SUMMARY_NAMES)]

        inverse = None
        asked = {
            "inverse_depth_m": inverse_depth_m,
            "inverse_depth_resolution_m": inverse_depth_resolution_m,
        }
        given = [n for n, v in asked.items() if v is not None]
        if len(given) == 1:
            (missing,) = set(asked) - set(given)
            return [_error(missing, f"{missing} is required with {given[0]}", "missing")]
        if inverse_depth_m is not None and inverse_depth_resolution_m is not None:
            try:
                baseline = rig.required_baseline_mm(
                    inverse_depth_m, inverse_depth_resolution_m, disparity_step_px
                )
            except _LIBRARY_ERRORS as exc:
                return [_library_error(exc, _INVERSE_NAMES)]
            inverse = {
                "depth_m": inverse_depth_m,
                "depth_resolution_m": inverse_depth_resolution_m,
                "disparity_step_px": disparity_step_px,
                "focal_px": rig.focal_px,
                "required_baseline_mm": baseline,
            }
    return {"summary": summary, "inverse": inverse, "charts": charts}


# --- the API ------------------------------------------------------------------------------
_api = APIRouter()
_REPEATABLE = {"table_disparities_px"}


def known_parameters(
    route: str, names: Iterable[str] = (), repeatable: Iterable[str] = (), *, body: bool = False
) -> Callable[[Request], None]:
    """A dependency answering 422 for a query parameter ``route`` does not have (a misspelt
    one was ignored: the answer came without it) or a single-valued one given more than once
    (the last one was used), each at its parameter. Every route of the API takes one, so all
    refuse what /api/calc refuses (the point query ignored ``?x=1&y=2&z=3`` without a word).
    ``body``: the route takes its fields in a JSON body, which the message says."""
    known = tuple(names)
    several = frozenset(repeatable)
    listed = f"its parameters: {', '.join(known)}" if known else "it takes none"
    if body:
        listed += ": its fields go in the JSON body"

    def check(request: Request) -> None:
        errors = []
        for name in dict.fromkeys(request.query_params.keys()):
            values = request.query_params.getlist(name)
            shown = ", ".join(repr(v[:40]) for v in values[:3])
            if name not in known:
                msg = f"{name[:40]} is not a parameter of {route}, got {shown} ({listed})"
                errors.append({"loc": ("query", name[:40]), "msg": msg, "type": "extra_forbidden"})
            elif len(values) > 1 and name not in several:
                msg = f"{name} is given {len(values)} times ({shown}): give it once"
                errors.append({"loc": ("query", name), "msg": msg, "type": "repeated"})
        if errors:
            raise RequestValidationError(errors)

    return check


#: Refuses a parameter /api/calc does not have, and one other than table_disparities_px given
#: more than once.
_only_known_parameters = known_parameters("/api/calc", FIELDS, _REPEATABLE)


@_api.get(
    "/api/calc",
    response_model=CalcResponse,
    responses={422: {"model": ErrorResponse, "description": "Bad input"}},
    summary="Depth, depth resolution, field of view, table and charts of a stereo rig",
    description="Unknown parameters, and a parameter other than table_disparities_px given "
    "more than once, answer 422 at that parameter.",
    dependencies=[Depends(_only_known_parameters)],
)
def calc(
    baseline_mm: Annotated[float, FIELDS["baseline_mm"].query()],
    focal_mm: Annotated[float | None, FIELDS["focal_mm"].query()] = None,
    pixel_um: Annotated[float | None, FIELDS["pixel_um"].query()] = None,
    focal_px: Annotated[float | None, FIELDS["focal_px"].query()] = None,
    doffs_px: Annotated[float | None, FIELDS["doffs_px"].query()] = None,
    width_px: Annotated[int | None, FIELDS["width_px"].query()] = None,
    height_px: Annotated[int | None, FIELDS["height_px"].query()] = None,
    disparity_px: Annotated[float | None, FIELDS["disparity_px"].query()] = None,
    disparity_step_px: Annotated[float | None, FIELDS["disparity_step_px"].query()] = None,
    max_disparity_px: Annotated[float | None, FIELDS["max_disparity_px"].query()] = None,
    table_disparities_px: Annotated[
        list[Annotated[float, PydanticField(ge=0, le=1e6, allow_inf_nan=False)]] | None,
        Query(
            description=f"{FIELDS['table_disparities_px'].description} (px): "
            f"{FIELDS['table_disparities_px'].rule}; repeat the parameter",
            max_length=_TABLE_MAX_ROWS,
        ),
    ] = None,
    inverse_depth_m: Annotated[float | None, FIELDS["inverse_depth_m"].query()] = None,
    inverse_depth_resolution_m: Annotated[
        float | None, FIELDS["inverse_depth_resolution_m"].query()
    ] = None,
) -> JSONResponse:
    result = calculate(
        baseline_mm=baseline_mm,
        focal_mm=focal_mm,
        pixel_um=pixel_um,
        focal_px=focal_px,
        doffs_px=doffs_px,
        width_px=width_px,
        height_px=height_px,
        disparity_px=disparity_px,
        disparity_step_px=1.0 if disparity_step_px is None else disparity_step_px,
        max_disparity_px=max_disparity_px,
        table_disparities_px=table_disparities_px,
        inverse_depth_m=inverse_depth_m,
        inverse_depth_resolution_m=inverse_depth_resolution_m,
    )
    if isinstance(result, list):
        return _unprocessable(result)
    # Returned as is (not through the response model), so the numbers are the library's.
    return JSONResponse(result)


@_api.get(
    "/api/fields",
    summary="The parameters of /api/calc: units and allowed ranges",
    description="Takes no parameters: any answers 422 at it.",
    dependencies=[Depends(known_parameters("/api/fields"))],
)
def fields() -> dict[str, Any]:
    return {"version": __version__, "fields": [x.to_dict() for x in FIELDS.values()]}


# --- the app ----------------------------------------------------------------------------------
def _plotly_js() -> Path:
    """plotly.min.js as shipped in the plotly package (no CDN)."""
    return Path(str(resources.files("plotly") / "package_data" / "plotly.min.js"))


class HeadAsGet:
    """ASGI middleware: a HEAD request is routed as a GET, and its answer is sent without the
    body (the same status and headers, Content-Length included), as RFC 9110, section 9.3.2
    asks. FastAPI's GET routes, unlike Starlette's, answered HEAD with 405."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return

        async def headers_only(message: Any) -> None:
            if message["type"] == "http.response.body":
                message = {**message, "body": b""}
            await send(message)

        await self.app({**scope, "method": "GET"}, receive, headers_only)


def create_app(
    *,
    max_upload_bytes: int = DEFAULT_MAX_UPLOAD_BYTES,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    allowed_hosts: Iterable[str] | None = None,
) -> FastAPI:
    """The web calculator's app: the page at ``/``, the API under ``/api``, with the depth-map
    view's upload limits (bytes per image file, pixels per image; see
    :mod:`stereodepth.web.depthmap`).

    The app answers only requests whose Host header is one of ``allowed_hosts`` (against DNS
    rebinding; :mod:`stereodepth.web.host`), under whichever server runs it: by default
    (None) ``localhost``, ``127.0.0.1`` and ``[::1]`` (``LOOPBACK_HOSTS``) at the port the
    server listens on, and the IP address the connection came in on; others answer 400 at
    ``["header", "host"]``. A list is all the names answered, in place of the default (unlike
    ``serve --allow-host``, which adds to its names): to keep the default's, include them,
    ``allowed_hosts=[*LOOPBACK_HOSTS, "depth.lab:8080"]`` (``from stereodepth.web import
    LOOPBACK_HOSTS``).
    Entries are names or IP addresses, each optionally with ``:port``; ``0.0.0.0`` or ``::``
    stands for any IP address, ``"*"`` turns the check off (behind a proxy that checks the
    Host itself). ``stereodepth serve`` passes these with its ``--host``, the address it bound
    and, bound to every interface, ``0.0.0.0`` and the machine's host name, and the entries of
    its ``--allow-host`` options. Under ``uvicorn
    --factory``, a factory of your own passes them (``def app(): return
    create_app(allowed_hosts=[*LOOPBACK_HOSTS, ...])``, then ``uvicorn mymodule:app
    --factory``).

    Raises TypeError for a limit that is not an integer or ``allowed_hosts`` that is not a
    list of strings, ValueError for a limit < 1 or an entry of ``allowed_hosts`` that is not
    a host name, an IP address, either with ``:port``, or ``"*"``."""
    limits = DepthMapLimits(max_upload_bytes=max_upload_bytes, max_pixels=max_pixels)
    hosts = AllowedHosts(allowed_hosts)
    app = FastAPI(
        title="stereodepth calculator",
        version=__version__,
        description=(
            "The stereo depth calculator of the stereodepth library: depth, depth resolution, "
            "field of view and the baseline for a wanted depth error, for a rectified stereo "
            "pair. The same numbers as StereoRig.summary() and `stereodepth calc --json`."
        ),
        # The interactive docs load their scripts from a CDN; the page must work offline.
        docs_url=None,
        redoc_url=None,
    )

    # Before every route (and inside security_headers, so that its 400 has the headers too).
    app.add_middleware(HostCheck, allowed=hosts)
    # Outermost: HEAD answers as GET, headers only (FastAPI's GET routes answered it 405).
    app.add_middleware(HeadAsGet)

    @app.middleware("http")
    async def security_headers(request: Request, call_next: Any) -> Response:
        response: Response = await call_next(request)
        response.headers.update(_SECURITY_HEADERS)
        return response

    @app.exception_handler(RequestValidationError)
    async def request_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        return _unprocessable([_request_error(e) for e in exc.errors()])

    app.include_router(_api)
    app.include_router(make_router(limits))

    plotly_js = _plotly_js()

    @app.get("/vendor/plotly.min.js", include_in_schema=False)
    def plotly() -> FileResponse:
        return FileResponse(
            plotly_js,
            media_type="text/javascript",
            headers={"Cache-Control": "public, max-age=86400"},
        )

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(
            STATIC_DIR / "index.html", media_type="text/html", headers={"Cache-Control": "no-cache"}
        )

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    return app
