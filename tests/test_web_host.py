"""The app's own Host-header check (against DNS rebinding), whichever server runs it: the ASGI
test client, the app mounted in another app, and real uvicorn processes on a free loopback
port started as ``uvicorn stereodepth.web.app:create_app --factory`` (no ``stereodepth
serve``, which had been the only entry point with the check) and with a factory of one's own
that sets ``allowed_hosts``."""

from __future__ import annotations

import json
import re
import socket
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("fastapi", reason="the web extra is not installed")
pytest.importorskip("uvicorn", reason="the web extra is not installed")

from fastapi.testclient import TestClient
from server_process import ServerProcess
from starlette.applications import Starlette
from starlette.routing import Mount

import stereodepth.web.host
from stereodepth.web import LOOPBACK_HOSTS
from stereodepth.web.app import create_app
from stereodepth.web.host import AllowedHosts


def refusal(r: Any) -> str:
    """The message of a 400 for the Host header."""
    assert r.status_code == 400, r.text
    (item,) = r.json()["detail"]
    assert item["loc"] == ["header", "host"] and item["type"] == "invalid_host", item
    assert "\n" not in item["msg"]
    return str(item["msg"])


# --- the ASGI test client --------------------------------------------------------------------
@pytest.fixture(scope="module")
def app() -> Any:
    return create_app()


@pytest.mark.parametrize(
    "base_url", ["http://localhost", "http://127.0.0.1:8000", "http://[::1]:8000"]
)
def test_the_app_answers_loopback_hosts_at_its_port(app: Any, base_url: str) -> None:
    assert TestClient(app, base_url=base_url).get("/api/fields").status_code == 200


#: The end of a refusal that cannot name the entry that would answer the Host.
ANY_NAME_HINT = (
    "(to answer a name: stereodepth serve --allow-host NAME[:PORT], "
    "or create_app(allowed_hosts=[*LOOPBACK_HOSTS, ...]) with LOOPBACK_HOSTS from "
    "stereodepth.web)"
)


@pytest.mark.parametrize(
    ("host", "entry"),
    [
        ("evil.example.com", "evil.example.com:80"),  # no port: 80
        ("evil.example.com:8000", "evil.example.com:8000"),
        ("localhost.evil.example.com:8000", "localhost.evil.example.com:8000"),
        ("127.0.0.1:8001", "127.0.0.1:8001"),  # another port: not this server
        ("127.0.0.1", "127.0.0.1:80"),
        ("testserver", "testserver:80"),
        ("", None),
        ("[::1", None),
    ],
)
@pytest.mark.parametrize("path", ["/api/fields", "/", "/api/calc?baseline_mm=1&focal_px=1"])
def test_the_app_refuses_another_host(app: Any, host: str, entry: str | None, path: str) -> None:
    client = TestClient(app, base_url="http://127.0.0.1:8000")
    msg = refusal(client.get(path, headers={"host": host}))
    hint = (
        ANY_NAME_HINT
        if entry is None
        else f"(to answer it: stereodepth serve --allow-host {entry}, "
        f"or create_app(allowed_hosts=[*LOOPBACK_HOSTS, {entry!r}]) with LOOPBACK_HOSTS from "
        "stereodepth.web)"
    )
    assert msg == (
        "the Host header must name this server (localhost:8000, 127.0.0.1:8000 or "
        f"[::1]:8000), got Host {host!r}: a page of another site cannot use it {hint}"
    )
    # The security headers are on the refusal too.
    assert (
        "default-src 'self'"
        in client.get(path, headers={"host": host}).headers["content-security-policy"]
    )


def test_the_rebinding_post_is_refused_before_its_body_is_read(app: Any) -> None:
    client = TestClient(app, base_url="http://127.0.0.1:8000")
    r = client.post(
        "/api/depthmap", json={"sample": True}, headers={"host": "evil.example.com:8000"}
    )
    refusal(r)


@pytest.mark.parametrize(
    ("base_url", "host"),
    [
        ("http://127.0.0.1:8000", "localhost:8080"),  # docker -p 8080:8000
        ("http://127.0.0.1:8000", "MyRobot.local:8000"),
        ("http://127.0.0.1:8000", "proxy.example"),  # a proxy that passes its Host: port 80
        ("https://127.0.0.1:8000", "proxy.example"),  # over https: port 443
        ("http://127.0.0.1:8000", "[fe80::1]:8000"),
        ("http://127.0.0.1:8000", "192.0.2.7"),
    ],
)
def test_the_entry_that_the_refusal_names_answers_the_host(base_url: str, host: str) -> None:
    msg = refusal(TestClient(create_app(), base_url=base_url).get("/", headers={"host": host}))
    found = re.search(
        r"\(to answer it: stereodepth serve --allow-host (\S+), or "
        r"create_app\(allowed_hosts=\[\*LOOPBACK_HOSTS, (.+)\]\) with LOOPBACK_HOSTS from "
        r"stereodepth\.web\)$",
        msg,
    )
    assert found, msg
    entry = found.group(1)
    assert found.group(2) == repr(entry)
    if base_url.startswith("https") and ":" not in host:
        assert entry == f"{host}:443"
    # As the refusal says: the Host is answered, and so are the loopback names still.
    client = TestClient(create_app(allowed_hosts=[*LOOPBACK_HOSTS, entry]), base_url=base_url)
    assert client.get("/api/fields", headers={"host": host}).status_code == 200
    for loopback in ("localhost:8000", "127.0.0.1:8000", "[::1]:8000"):
        assert client.get("/api/fields", headers={"host": loopback}).status_code == 200


def test_allowed_hosts_is_the_whole_list() -> None:
    """``allowed_hosts`` replaces the default (``serve --allow-host`` adds to it); the default
    is :data:`LOOPBACK_HOSTS`, from ``stereodepth.web`` as the refusal says."""
    assert LOOPBACK_HOSTS == ("localhost", "127.0.0.1", "[::1]")
    assert LOOPBACK_HOSTS is stereodepth.web.host.LOOPBACK_HOSTS
    only = TestClient(create_app(allowed_hosts=["box:8000"]), base_url="http://10.0.0.1:8000")
    assert only.get("/api/fields", headers={"host": "box:8000"}).status_code == 200
    msg = refusal(only.get("/api/fields", headers={"host": "localhost:8000"}))
    assert msg.startswith("the Host header must name this server (box:8000 or 10.0.0.1:8000)")


@pytest.mark.parametrize(
    "host",
    [
        "a;rm -rf x",  # not a name to show as a command line
        "$(x).example",
        "a'b",
        "x" * 61,  # longer than the refusal shows
    ],
)
def test_the_refusal_of_an_odd_host_shows_the_form_of_an_entry(host: str) -> None:
    client = TestClient(create_app(), base_url="http://127.0.0.1:8000")
    msg = refusal(client.get("/api/fields", headers={"host": host}))
    assert msg.endswith(f"a page of another site cannot use it {ANY_NAME_HINT}"), msg


def test_the_client_default_host_is_refused_with_the_hosts_answered() -> None:
    msg = refusal(TestClient(create_app()).get("/api/fields"))
    assert "localhost:80" in msg and "got Host 'testserver'" in msg


def test_the_connections_own_ip_address_is_answered(app: Any) -> None:
    # uvicorn --host 0.0.0.0 reached at a LAN address: the scope's server is that address.
    client = TestClient(app, base_url="http://192.0.2.7:8000")
    assert client.get("/api/fields").status_code == 200
    assert "192.0.2.7:8000" in refusal(client.get("/api/fields", headers={"host": "x.example"}))


@pytest.mark.parametrize(
    ("allowed", "answered", "refused"),
    [
        pytest.param(["calc.lan"], ["calc.lan:8000"], ["localhost:8000", "calc.lan:80"], id="name"),
        pytest.param(
            ["localhost:8080"],
            ["localhost:8080"],
            ["localhost:8000", "127.0.0.1:8080"],
            id="port-mapping",
        ),
        pytest.param(
            ["0.0.0.0"],
            ["10.1.2.3:8000", "[fe80::1]:8000", "127.0.0.1:8000"],
            ["localhost:8000", "10.1.2.3:8001", "evil.example.com:8000"],
            id="any-address",
        ),
        pytest.param(["::1"], ["[::1]:8000", "[0:0:0:0:0:0:0:1]:8000"], ["[::2]:8000"], id="ipv6"),
        pytest.param(["*"], ["evil.example.com", "x:1"], [], id="any-host"),
        # A browser sends a name of other than ASCII characters in its IDNA form.
        pytest.param(
            ["Ünïcode.LOCAL", "日本.example:8080"],
            ["xn--ncode-cta3g.local:8000", "XN--NCODE-CTA3G.Local:8000", "xn--wgv71a.example:8080"],
            ["xn--ncode-cta3g.local:8001", "ncode.local:8000", "xn--wgv71a.example:8000"],
            id="idna",
        ),
    ],
)
def test_allowed_hosts_sets_the_hosts_answered(
    allowed: list[str], answered: list[str], refused: list[str]
) -> None:
    client = TestClient(create_app(allowed_hosts=allowed), base_url="http://127.0.0.1:8000")
    for host in answered:
        assert client.get("/api/fields", headers={"host": host}).status_code == 200, host
    for host in refused:
        refusal(client.get("/api/fields", headers={"host": host}))


def test_a_mounted_app_checks_the_host() -> None:
    outer = Starlette(routes=[Mount("/calc", app=create_app())])
    client = TestClient(outer, base_url="http://localhost:8000")
    assert client.get("/calc/api/fields").status_code == 200
    refusal(client.get("/calc/api/fields", headers={"host": "evil.example.com:8000"}))


@pytest.mark.parametrize(
    ("hosts", "error", "msg"),
    [
        ("localhost", TypeError, "allowed_hosts must be a list of host names, got 'localhost' "),
        (5, TypeError, "allowed_hosts must be a list of host names, got 5"),
        ([5], TypeError, "allowed_hosts must hold strings, got 5"),
        (["http://x"], ValueError, "allowed_hosts must hold host names or IP addresses"),
        (["x:port"], ValueError, "got 'x:port'"),
        ([""], ValueError, "got ''"),
        (["a b"], ValueError, "got 'a b'"),
        (["*.example.com"], ValueError, "got '*.example.com'"),  # no wildcards: never matched
        (["localhost:70000"], ValueError, "got 'localhost:70000'"),
        (["é..local"], ValueError, "got 'é..local' (IDNA cannot encode it: label empty or too"),
        (["ü" * 64 + ".local"], ValueError, "(IDNA cannot encode it: label empty or too long)"),
        (["ü/x"], ValueError, "got 'ü/x'"),  # IDNA passes the "/"
        (["ü\u00a0x"], ValueError, "got 'ü\\xa0x'"),  # IDNA maps the no-break space to " "
    ],
)
def test_bad_allowed_hosts_raise_naming_the_parameter(
    hosts: Any, error: type[Exception], msg: str
) -> None:
    with pytest.raises(error, match=re.escape(msg)):
        create_app(allowed_hosts=hosts)


def test_the_hosts_in_words() -> None:
    assert AllowedHosts().expected(8000) == "localhost:8000, 127.0.0.1:8000 or [::1]:8000"
    assert AllowedHosts().expected(None) == "localhost, 127.0.0.1 or [::1]"
    every = AllowedHosts(["localhost", "127.0.0.1", "0.0.0.0", "box"])
    assert every.expected(8000) == "localhost:8000, box:8000 or an IP address with :8000"


# --- real servers on loopback ----------------------------------------------------------------
class Uvicorn(ServerProcess):
    """``python -m uvicorn ... --port 0`` in a subprocess; its port from its log line."""

    def __init__(self, *args: str, path: Path | None = None) -> None:
        super().__init__(
            ["-m", "uvicorn", *args, "--host", "127.0.0.1", "--port", "0"],
            ready=r"Uvicorn running on http://127\.0\.0\.1:(\d+)",
            stream="stderr",
            extra_path=path,
        )
        self.port = int(self.ready.group(1))

    def get(self, host: str) -> tuple[int, Any]:
        """GET /api/fields with this Host header: the status and the JSON body."""
        request = f"GET /api/fields HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"
        with socket.create_connection(("127.0.0.1", self.port), timeout=10) as s:
            s.sendall(request.encode())
            answer = b""
            while chunk := s.recv(65536):
                answer += chunk
        head, _, body = answer.partition(b"\r\n\r\n")
        found = re.match(rb"HTTP/1\.[01] (\d{3})", head)
        assert found, answer[:200]
        return int(found.group(1)), json.loads(body)


def test_uvicorn_factory_refuses_another_host() -> None:
    server = Uvicorn("stereodepth.web.app:create_app", "--factory")
    try:
        port = server.port
        for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}"):
            assert server.get(host)[0] == 200, host
        for host in (f"evil.example.com:{port}", f"127.0.0.1:{port + 1}", "localhost"):
            status, body = server.get(host)
            assert status == 400, host
            (item,) = body["detail"]
            assert item["loc"] == ["header", "host"]
            assert repr(host) in item["msg"] and f"127.0.0.1:{port}" in item["msg"]
    finally:
        server.stop()
    assert "Traceback" not in "".join(server.log)


def test_a_factory_of_ones_own_sets_the_allowed_hosts(tmp_path: Path) -> None:
    (tmp_path / "my_calc.py").write_text(
        "from stereodepth.web.app import create_app\n\n\n"
        "def app():\n"
        "    return create_app(allowed_hosts=['calc.lan', 'localhost'])\n"
    )
    server = Uvicorn("my_calc:app", "--factory", path=tmp_path)
    try:
        port = server.port
        assert server.get(f"calc.lan:{port}")[0] == 200
        assert server.get(f"localhost:{port}")[0] == 200
        # Not listed (127.0.0.1, the address the connection came in on, is answered too).
        for host in (f"[::1]:{port}", f"evil.example.com:{port}"):
            status, body = server.get(host)
            assert status == 400, host
            assert (
                f"(calc.lan:{port}, localhost:{port} or 127.0.0.1:{port})"
                in (body["detail"][0]["msg"])
            )
    finally:
        server.stop()
