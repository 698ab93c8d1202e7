"""``stereodepth serve`` as a real process on a free loopback port, with real sockets and real
signals: a client that stalls or leaves mid-upload cannot hold the server or make it print a
traceback, either signal stops it with one line and exit status 0, and a request whose Host
is not this server (DNS rebinding) is refused with 400."""

from __future__ import annotations

import ipaddress
import json
import re
import signal
import socket
import time
import urllib.error
import urllib.request
from typing import Any

import pytest

pytest.importorskip("fastapi", reason="the web extra is not installed")
pytest.importorskip("uvicorn", reason="the web extra is not installed")

from server_process import ServerProcess
from server_process import serve as serve_process

from stereodepth.web import serve

#: The grace period of serve (seconds) for requests in flight.
GRACE_S: float = getattr(serve, "GRACE_S", 3.0)

CALIB = (
    "cam0=[1000 0 100; 0 1000 80; 0 0 1]\ndoffs=0\nbaseline=100\nwidth=200\nheight=160\nndisp=64\n"
)


def start(*args: str, names: dict[str, list[str]] | None = None) -> ServerProcess:
    """``stereodepth serve --port 0`` in a subprocess, its port from its first line (``names``:
    host names of the test's own, see :func:`server_process.serve`)."""
    return serve_process("--port", "0", *args, names=names)


def raw(port: int, request: bytes, *, read: bool = True) -> bytes:
    """Sends ``request`` as is on a new connection; the whole answer (the server closes)."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(request)
        if not read:
            return b""
        chunks = []
        while True:
            try:
                chunk = s.recv(65536)
            except TimeoutError:
                break
            if not chunk:
                break
            chunks.append(chunk)
    return b"".join(chunks)


def stalled_upload(port: int, path: str = "/api/depthmap", length: int = 100_000) -> socket.socket:
    """A connection that sent the headers of a JSON POST and a few bytes of its body, and
    then nothing more (kept open)."""
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    s.sendall(
        f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
        f"Content-Type: application/json\r\nContent-Length: {length}\r\n\r\n".encode()
        + b'{"left": "iVBO'
    )
    time.sleep(0.5)  # the server has read them and waits for the rest
    return s


def status_of(answer: bytes) -> int:
    head = answer.split(b"\r\n", 1)[0].decode("latin-1")
    found = re.match(r"HTTP/1\.[01] (\d{3})", head)
    assert found, answer[:200]
    return int(found.group(1))


def body_of(answer: bytes) -> Any:
    return json.loads(answer.split(b"\r\n\r\n", 1)[1])


# --- 1. a stalled upload cannot hold the server ---------------------------------------------------
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stalled_upload_does_not_keep_the_server_from_stopping(sig: int) -> None:
    server = start()
    stalled = stalled_upload(server.port)
    try:
        code, took, out, err = server.stop(sig, timeout=GRACE_S + 10)
    finally:
        stalled.close()
        server.kill()
    assert code == 0, (code, err)
    assert took < GRACE_S + 5, took
    assert "Traceback" not in err and "ERROR" not in err, err
    assert "stopped" in out


def test_a_second_ctrl_c_stops_at_once_without_a_traceback() -> None:
    server = start()
    stalled = stalled_upload(server.port)
    try:
        server.proc.send_signal(signal.SIGINT)
        time.sleep(0.3)
        code, took, _, err = server.stop(signal.SIGINT, timeout=GRACE_S + 10)
    finally:
        stalled.close()
        server.kill()
    assert code == 0, (code, err)
    assert took < GRACE_S, took
    assert "Traceback" not in err and "ERROR" not in err, err


def test_requests_in_flight_complete_within_the_grace_period() -> None:
    """A client whose upload arrives during the grace period gets its answer."""
    server = start()
    body = json.dumps({"calib": CALIB}).encode()
    conn = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    try:
        conn.sendall(
            f"POST /api/calib HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\n"
            f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n\r\n".encode()
            + body[:5]
        )
        time.sleep(0.3)
        server.proc.send_signal(signal.SIGTERM)
        time.sleep(0.5)
        conn.sendall(body[5:])
        answer = b""
        while chunk := conn.recv(65536):
            answer += chunk
    finally:
        conn.close()
    code, _, _, err = server.stop(signal.SIGTERM, timeout=GRACE_S + 10)
    server.kill()
    assert status_of(answer) == 200, answer
    assert body_of(answer)["baseline_mm"] == 100
    assert code == 0 and "Traceback" not in err, (code, err)


# --- 2. a client that leaves mid-upload -----------------------------------------------------------
@pytest.mark.parametrize("path", ["/api/depthmap", "/api/calib"])
def test_a_client_that_leaves_mid_upload_leaves_no_traceback(path: str) -> None:
    server = start()
    try:
        for _ in range(3):
            stalled_upload(server.port, path, length=100).close()
        time.sleep(0.5)
        # The server still answers.
        answer = raw(
            server.port,
            f"GET /api/fields HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\n"
            "Connection: close\r\n\r\n".encode(),
        )
        assert status_of(answer) == 200
    finally:
        code, _, _, err = server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
    assert code == 0
    assert "Traceback" not in err and "ClientDisconnect" not in err and "ERROR" not in err, err


# --- 3. signals and the exit status ---------------------------------------------------------------
@pytest.mark.parametrize(
    ("sig", "line"),
    [
        (signal.SIGINT, "stereodepth serve: stopped (Ctrl-C)"),
        (signal.SIGTERM, "stereodepth serve: stopped (SIGTERM)"),
    ],
    ids=["SIGINT", "SIGTERM"],
)
def test_either_signal_stops_the_server_with_one_line_and_status_0(sig: int, line: str) -> None:
    server = start()
    try:
        code, _, out, err = server.stop(sig, timeout=GRACE_S + 10)
    finally:
        server.kill()
    assert code == 0, (code, err)
    assert out.strip() == line, out
    assert err == "", err  # neither "terminated" nor "interrupted", nor a traceback


# --- 4. the Host header -------------------------------------------------------------------------
def get(
    port: int, host: str | None, http: str = "1.1", path: str = "/api/fields", method: str = "GET"
) -> bytes:
    head = f"{method} {path} HTTP/{http}\r\n"
    if host is not None:
        head += f"Host: {host}\r\n"
    return raw(port, (head + "Connection: close\r\n\r\n").encode())


@pytest.fixture(scope="module")
def loopback_server() -> Any:
    server = start()
    yield server
    server.stop(signal.SIGINT, timeout=GRACE_S + 10)
    server.kill()


@pytest.mark.parametrize(
    "host", ["127.0.0.1:{port}", "localhost:{port}", "LocalHost:{port}", "[::1]:{port}"]
)
def test_a_loopback_host_is_answered(loopback_server: ServerProcess, host: str) -> None:
    answer = get(loopback_server.port, host.format(port=loopback_server.port))
    assert status_of(answer) == 200, answer[:300]


@pytest.mark.parametrize(
    "path",
    ["/", "/api/fields", "/api/calc?baseline_mm=100&focal_px=800", "/static/app.js", "/nope"],
)
def test_head_answers_as_get_without_the_body(loopback_server: ServerProcess, path: str) -> None:
    # FastAPI's GET routes answered HEAD with 405 (curl -I, link checkers, uptime probes).
    port = loopback_server.port
    host = f"127.0.0.1:{port}"
    full, head = get(port, host, path=path), get(port, host, path=path, method="HEAD")
    assert status_of(head) == status_of(full) != 405, head[:300]
    full_head, body = full.split(b"\r\n\r\n", 1)
    head_head, nothing = head.split(b"\r\n\r\n", 1)
    assert nothing == b"" and body != b""

    def fields(block: bytes) -> dict[str, str]:
        lines = block.decode("latin-1").split("\r\n")[1:]
        pairs = (line.split(":", 1) for line in lines)
        return {k.strip().lower(): v.strip() for k, v in pairs if k.strip().lower() != "date"}

    assert fields(head_head) == fields(full_head)
    assert int(fields(head_head)["content-length"]) == len(body)


@pytest.mark.parametrize(
    "host",
    [
        "evil.example.com:{port}",
        "evil.example.com",
        "127.0.0.1:{other}",
        "127.0.0.1",
        "localhost.evil.example.com:{port}",
        "10.0.0.1:{port}",
        "",
    ],
)
def test_another_host_is_refused_with_400(loopback_server: ServerProcess, host: str) -> None:
    port = loopback_server.port
    shown = host.format(port=port, other=port + 1)
    for path in ("/api/fields", "/", "/api/calc?baseline_mm=1&focal_px=1"):
        answer = get(port, shown, path=path)
        assert status_of(answer) == 400, answer[:300]
        (item,) = body_of(answer)["detail"]
        assert item["loc"] == ["header", "host"]
        assert repr(shown) in item["msg"] and "\n" not in item["msg"], item
        assert f"127.0.0.1:{port}" in item["msg"]
    # The POST the rebinding page would make: refused before its body is read.
    answer = raw(
        port,
        f"POST /api/depthmap HTTP/1.1\r\nHost: {shown}\r\nContent-Type: application/json\r\n"
        'Content-Length: 15\r\nConnection: close\r\n\r\n{"sample":true}'.encode(),
    )
    assert status_of(answer) == 400


def test_a_request_without_host_is_refused(loopback_server: ServerProcess) -> None:
    answer = get(loopback_server.port, None, http="1.0")  # HTTP/1.0 may omit it
    assert status_of(answer) == 400
    (item,) = body_of(answer)["detail"]
    assert item["loc"] == ["header", "host"] and "no Host header" in item["msg"], item
    answer = get(loopback_server.port, None, http="1.1")  # HTTP/1.1 must have it (h11)
    assert status_of(answer) == 400


@pytest.mark.parametrize(
    ("host", "names", "shown"),
    [
        ("0.0.0.0", None, "0.0.0.0"),
        # A name for every interface: the warning says which address it is.
        ("anywhere.test", {"anywhere.test": ["0.0.0.0"]}, "anywhere.test (0.0.0.0)"),
    ],
)
def test_a_server_on_every_interface_answers_its_addresses_not_other_names(
    host: str, names: dict[str, list[str]] | None, shown: str
) -> None:
    server = start("--host", host, names=names)
    try:
        port = server.port
        # A page address that a browser can open on this machine (not http://0.0.0.0:PORT/),
        # and that the server answers.
        assert server.url == f"http://127.0.0.1:{port}/", server.first_line
        assert fetch(server.url)[0] == 200
        for name in (f"127.0.0.1:{port}", f"localhost:{port}", f"192.0.2.7:{port}"):
            assert status_of(get(port, name)) == 200, name
        for name in (f"evil.example.com:{port}", f"192.0.2.7:{port + 1}"):
            assert status_of(get(port, name)) == 400, name
    finally:
        code, _, _, err = server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
    assert code == 0, err
    assert err == (
        f"stereodepth serve: warning: listening on {shown}, which other machines may reach; "
        "the default 127.0.0.1 keeps the page on this machine\n"
    )


# --- 5. names for loopback, and the names --allow-host adds ---------------------------------------
def fetch(url: str, host: str | None = None) -> tuple[int, Any]:
    """GET ``url`` + ``api/fields`` as a browser opening ``url`` would (its Host from the URL),
    or with another Host: the status and the JSON body."""
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    request = urllib.request.Request(url + "api/fields", headers={"Host": host} if host else {})
    try:
        with opener.open(request, timeout=10) as r:
            return int(r.status), json.load(r)
    except urllib.error.HTTPError as e:
        with e:
            return int(e.code), json.load(e)


@pytest.mark.parametrize(
    ("name", "address", "url_host"),
    [
        ("vm.test", "127.0.0.1", "127.0.0.1"),
        ("VM.test", "127.0.0.1", "127.0.0.1"),
        ("myhost.test", "127.0.1.1", "127.0.1.1"),  # Debian's line for the machine's own name
        ("vm6.test", "::1", "[::1]"),
    ],
)
def test_a_name_for_loopback_is_not_warned_about_and_its_url_is_answered(
    name: str, address: str, url_host: str
) -> None:
    """``--host NAME``, NAME a name for a loopback address (as /etc/hosts maps the machine's
    own name): no warning that other machines may reach it, and the page's address printed is
    where it listens and answered by its Host check, as is the name."""
    server = start("--host", name, names={name.lower(): [address]})
    try:
        port = server.port
        assert server.url == f"http://{url_host}:{port}/", server.first_line
        status, body = fetch(server.url)
        assert status == 200, body
        assert fetch(server.url, f"{name}:{port}")[0] == 200
        assert fetch(server.url, f"evil.example.com:{port}")[0] == 400
    finally:
        code, _, _, err = server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
    assert code == 0, err
    assert err == "", err


@pytest.mark.parametrize("host", ["[::1]", "::1", " [::1] "])
def test_an_ipv6_host_in_brackets_is_listened_on(host: str) -> None:
    """``--host [::1]``, as a URL spells it (and as the help does): the address without its
    brackets, no warning; its page's address answered."""
    server = start("--host", host)
    try:
        assert server.url == f"http://[::1]:{server.port}/", server.first_line
        assert fetch(server.url)[0] == 200
    finally:
        code, _, _, err = server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
    assert code == 0, err
    assert err == "", err


def test_the_machines_own_name_for_loopback_is_not_warned_about() -> None:
    """The same with this machine's real name and resolver, when it maps it to loopback."""
    name = socket.gethostname()
    try:
        infos = socket.getaddrinfo(name, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except OSError:
        pytest.skip(f"this machine's name {name!r} does not resolve")
    addresses = {str(info[4][0]) for info in infos}
    if not all(ipaddress.ip_address(a).is_loopback for a in addresses):
        pytest.skip(f"this machine's name {name!r} is not loopback only: {sorted(addresses)}")
    server = start("--host", name)
    try:
        assert fetch(server.url)[0] == 200, server.first_line
        assert fetch(server.url, f"{name}:{server.port}")[0] == 200
    finally:
        code, _, _, err = server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
    assert code == 0 and err == "", (code, err)


def test_allow_host_adds_names_at_their_ports() -> None:
    """Docker's ``-p 8080:PORT`` (``Host: localhost:8080``) and a robot's mDNS name at the
    server's own port; the names answered before still are, other names and ports are not."""
    server = start("--allow-host", "localhost:8080", "--allow-host", "MyRobot.local")
    try:
        port = server.port
        for host in ("localhost:8080", f"myrobot.local:{port}", f"127.0.0.1:{port}"):
            assert status_of(get(port, host)) == 200, host
        for host in ("127.0.0.1:8080", f"myrobot.local:{port + 1}", "myrobot.local"):
            answer = get(port, host)
            assert status_of(answer) == 400, host
            (item,) = body_of(answer)["detail"]
            assert f"[::1]:{port}, localhost:8080 or myrobot.local:{port})" in item["msg"]
    finally:
        code, _, _, err = server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
    assert code == 0 and err == "", (code, err)


def test_allow_host_answers_a_name_of_other_than_ascii_in_its_idna_form() -> None:
    """The Host a browser sends for ``Ünïcode.local`` is its IDNA form, in any case."""
    server = start("--allow-host", "Ünïcode.local")
    try:
        port = server.port
        for host in (f"xn--ncode-cta3g.local:{port}", f"XN--NCODE-CTA3G.LOCAL:{port}"):
            assert status_of(get(port, host)) == 200, host
        answer = get(port, f"xn--ncode-cta3g.local:{port + 1}")
        assert status_of(answer) == 400
        (item,) = body_of(answer)["detail"]
        assert f"[::1]:{port} or xn--ncode-cta3g.local:{port})" in item["msg"], item
    finally:
        code, _, _, err = server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
    assert code == 0 and err == "", (code, err)


def test_allow_host_star_answers_every_host_with_a_warning() -> None:
    server = start("--allow-host", "*")
    try:
        for host in ("evil.example.com", f"10.0.0.1:{server.port + 1}"):
            assert status_of(get(server.port, host)) == 200, host
    finally:
        code, _, _, err = server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
    assert code == 0, err
    assert err == (
        "stereodepth serve: warning: --allow-host '*' answers every Host header, which turns "
        "off the check against DNS rebinding: only behind a proxy that checks the Host itself\n"
    )


@pytest.mark.parametrize(
    ("host", "entry"),
    [("myrobot.local:{port}", "myrobot.local:{port}"), ("proxy.example", "proxy.example:80")],
)
def test_the_refusal_says_how_to_answer_the_host(host: str, entry: str) -> None:
    """The 400 names the --allow-host that answers that Host, and that one does."""
    server = start()
    try:
        port = server.port
        answer = get(port, host.format(port=port))
        assert status_of(answer) == 400
        (item,) = body_of(answer)["detail"]
        entry = entry.format(port=port)
        assert item["msg"].endswith(
            f"a page of another site cannot use it (to answer it: stereodepth serve "
            f"--allow-host {entry}, or create_app(allowed_hosts=[*LOOPBACK_HOSTS, {entry!r}]) "
            "with LOOPBACK_HOSTS from stereodepth.web)"
        ), item
    finally:
        server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
    server = start("--allow-host", entry)
    try:
        assert status_of(get(server.port, host.format(port=port))) == 200
        # --allow-host adds to the names answered: the loopback ones still are.
        for loopback in ("localhost", "127.0.0.1", "[::1]"):
            assert status_of(get(server.port, f"{loopback}:{server.port}")) == 200, loopback
    finally:
        server.stop(signal.SIGINT, timeout=GRACE_S + 10)
        server.kill()
