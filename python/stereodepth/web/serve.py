"""``stereodepth serve``: the calculator as a local web page (FastAPI app on uvicorn).

Listens on 127.0.0.1 (this machine only) unless ``--host`` says otherwise (a warning on
stderr when the address it binds is not a loopback one), and prints the page's address on
start-up; answers only requests whose Host header names this server (:func:`allowed_hosts`,
which the app checks itself, :mod:`stereodepth.web.host`: 400 for others, against DNS
rebinding), and the names that ``--allow-host`` adds (a port mapping, a robot's mDNS name, a
reverse proxy). ``--port 0`` takes any free port. Ctrl+C (or SIGTERM) stops it: the requests in
flight get :data:`GRACE_S` (3) seconds to finish, then the connections still open are
closed (a depth map already being matched is finished first: its worker thread cannot be
interrupted); a second Ctrl+C closes them at once. Either signal is the server's normal end:
it prints one line, ``stereodepth serve: stopped (Ctrl-C)`` or ``stopped (SIGTERM)``, on
stdout and exits with status 0 (not the command line's 130 and 143 for other commands).
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import ipaddress
import signal
import socket
import sys
import threading
from collections.abc import Iterator, Sequence
from typing import Any

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8000
# The depth-map view's upload limits (stereodepth.web.depthmap's defaults).
DEFAULT_MAX_UPLOAD_MB = 20.0
DEFAULT_MAX_MEGAPIXELS = 4.0
#: Seconds that the requests in flight get to finish once the server is told to stop; then
#: it closes every connection still open, so that a stalled or slow client (an upload that
#: never ends, an answer never read) cannot keep it running.
GRACE_S = 3.0
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_SIGNAL_NAMES: dict[int, str] = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}


class _Stopped(Exception):
    """A signal before the server ran (while the web extra loads)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def _signals_stop() -> Iterator[None]:
    """For the block's duration SIGINT and SIGTERM raise :class:`_Stopped` (the server,
    once running, handles them itself). The command line's handlers (Ctrl-C's
    KeyboardInterrupt, SIGTERM's ``Terminated``) would make a server's normal end an
    'interrupted' (130) or 'terminated' (143). A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, frame: Any) -> None:
        raise _Stopped(signum)

    previous = {sig: signal.signal(sig, stop) for sig in _STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def register(subparsers: Any) -> None:
    """Adds the ``serve`` subcommand."""
    p = subparsers.add_parser(
        "serve",
        help="the calculator and a depth-map view of a stereo pair as a local web page",
        description=(
            "Serves the stereo depth calculator as a web page: inputs, live results, the "
            "disparity-to-depth table and charts, all from the library's JSON API "
            "(/api/calc; schema at /openapi.json); and a depth-map view that matches an "
            "uploaded pair (or a built-in sample) and reads depth under the cursor "
            "(/api/depthmap). Uploads are limited in size (--max-upload-mb, "
            "--max-megapixels), decoded in memory and matched in worker threads. Needs the "
            "'web' extra (and 'plot' for the colour maps)."
        ),
    )
    p.add_argument(
        "--host",
        default=DEFAULT_HOST,
        help=f"address to listen on (default {DEFAULT_HOST}: this machine only; an IPv6 one "
        "with or without brackets, [::1] or ::1; 0.0.0.0 or [::]: every interface)",
    )
    p.add_argument(
        "--port",
        type=int,
        default=DEFAULT_PORT,
        help=f"TCP port (default {DEFAULT_PORT}; 0: any free port)",
    )
    p.add_argument(
        "--allow-host",
        action="append",
        metavar="NAME[:PORT]",
        help="also answer requests whose Host header is NAME at the port the server listens "
        "on, or NAME:PORT (the port the browser uses, which a Host without one gives as 80): "
        "a port mapping (docker -p 8080:8000: localhost:8080 and 127.0.0.1:8080), an mDNS name "
        "(myrobot.local), a reverse proxy's name; repeat it for more. Others get 400, "
        "against DNS rebinding (by default only localhost, 127.0.0.1, [::1], --host and the "
        "address bound are answered). A name of other than ASCII characters is answered in "
        "the IDNA form browsers send (xn--...). 0.0.0.0: any IP address; '*': every Host, no "
        "check, only behind a proxy that checks the Host itself",
    )
    p.add_argument("--open", action="store_true", help="open the page in a web browser")
    p.add_argument(
        "--max-upload-mb",
        type=float,
        default=DEFAULT_MAX_UPLOAD_MB,
        help="depth-map view: largest image file accepted, in MB "
        f"(default {DEFAULT_MAX_UPLOAD_MB:g})",
    )
    p.add_argument(
        "--max-megapixels",
        type=float,
        default=DEFAULT_MAX_MEGAPIXELS,
        help="depth-map view: largest image accepted, in megapixels "
        f"(default {DEFAULT_MAX_MEGAPIXELS:g})",
    )
    p.set_defaults(func=run)


def _ip_of(sock: socket.socket) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    """The IP address a socket is bound to (an IPv4-mapped IPv6 one as IPv4)."""
    ip = ipaddress.ip_address(str(sock.getsockname()[0]).partition("%")[0])
    mapped = getattr(ip, "ipv4_mapped", None)
    return mapped if mapped is not None else ip


def is_loopback(sock: socket.socket) -> bool:
    """Whether a bound socket is reachable from this machine only: bound to a loopback
    address, whichever name ``--host`` gave for it (``localhost``, or the machine's own name
    that /etc/hosts maps to 127.0.0.1 or 127.0.1.1)."""
    return _ip_of(sock).is_loopback


def allow_hosts(entries: Sequence[str] | None) -> list[str]:
    """The ``--allow-host`` entries (None: none), checked: ValueError naming the option and the
    first one that is not a host name or IP address, optionally with ``:PORT``, or ``'*'`` (a
    name of other than ASCII characters is answered in its IDNA form, ``xn--...``)."""
    from .host import AllowedHosts, _BadEntry

    for entry in entries or ():
        try:
            AllowedHosts([entry])
        except _BadEntry as exc:
            raise ValueError(
                "--allow-host must be a host name or IP address, optionally with :PORT "
                f"(1 to 65535), or '*', got {entry[:60]!r}{exc.why}"
            ) from None
    return list(entries or ())


def unbracketed(host: str) -> str:
    """``--host`` without the brackets of an IPv6 address (``[::1]``: ``::1``), and spaces."""
    host = host.strip()
    ipv6 = host.startswith("[") and host.endswith("]") and ":" in host
    return host[1:-1] if ipv6 else host


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host`` (an IPv6 address with or without its brackets):
    ``port`` (0: a free port), or ValueError naming ``--host`` (not an address of this
    machine) or ``--port`` (taken, or not allowed)."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ValueError(f"--port must be an integer from 0 to 65535, got {port!r}")
    try:
        infos = socket.getaddrinfo(
            unbracketed(host), port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )
    except socket.gaierror as exc:
        raise ValueError(
            f"--host must be an address of this machine, got {host!r} ({exc.strerror})"
        ) from None
    family, kind, proto, _, address = infos[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(128)
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRNOTAVAIL:  # the address, not the port
            raise ValueError(
                f"--host {host} is not an address of this machine ({exc.strerror or exc}): "
                "give one of its own, 127.0.0.1 (this machine only) or 0.0.0.0 (every "
                "interface)"
            ) from None
        raise ValueError(
            f"cannot listen on {host} port {port}: {exc.strerror or exc}; "
            "choose another --port (0 takes any free port)"
        ) from None
    return sock


def url_of(sock: socket.socket) -> str:
    """The page's address for a bound socket: at the address bound, which the server's Host
    check answers whatever name ``--host`` gave for it; bound to every interface (``0.0.0.0``,
    ``::``), at the loopback address of that family (a browser cannot open ``0.0.0.0`` on
    every system)."""
    host, port = sock.getsockname()[:2]
    if _ip_of(sock).is_unspecified:
        host = "127.0.0.1" if sock.family == socket.AF_INET else "::1"
    if sock.family == socket.AF_INET6:
        host = f"[{host}]"
    return f"http://{host}:{port}/"


def allowed_hosts(host: str, sock: socket.socket, extra: Sequence[str] = ()) -> list[str]:
    """The Host header values the server answers (``create_app``'s ``allowed_hosts``): at the
    port it listens on, ``localhost``, ``127.0.0.1``, ``[::1]``, the ``--host`` given and the
    address bound; when bound to every interface (``0.0.0.0``, ``::``), also any IP address (a
    page loaded from an address is this server's own) and this machine's host name; then the
    ``extra`` entries (``--allow-host``, checked by :func:`allow_hosts`)."""
    from .host import LOOPBACK_HOSTS, AllowedHosts

    bound = str(sock.getsockname()[0])
    hosts = [*LOOPBACK_HOSTS, host.strip(), bound]
    try:
        every_interface = ipaddress.ip_address(bound).is_unspecified
    except ValueError:
        every_interface = False
    if every_interface:
        hosts.append(socket.gethostname().lower())

    def usable(name: str) -> bool:  # a --host that getaddrinfo took but no Host can name
        try:
            AllowedHosts([name])
        except ValueError:
            return False
        return True

    return [h for h in hosts if usable(h)] + list(extra)


def _server(uvicorn: Any, config: Any) -> Any:
    """A ``uvicorn.Server`` whose shutdown gives the requests in flight :data:`GRACE_S`
    seconds and then closes the connections still open (uvicorn's own waits for every
    client to finish, however long it takes). A second signal closes them at once, where
    uvicorn's cancelled the requests' tasks and logged each with a traceback."""

    class Server(uvicorn.Server):  # type: ignore[misc]
        hurry = False
        #: The signal that stopped the server (None: not a signal).
        stopped_by: int | None = None

        @contextlib.contextmanager
        def capture_signals(self) -> Iterator[None]:
            # uvicorn's raised the signal again once the server had stopped: KeyboardInterrupt
            # for Ctrl-C, and for SIGTERM the command line's "terminated" and exit status 143.
            # A signal is how a server ends; run() says which one stopped it.
            if threading.current_thread() is not threading.main_thread():
                yield
                return
            previous = {sig: signal.signal(sig, self.handle_exit) for sig in _STOP_SIGNALS}
            try:
                yield
            finally:
                for sig, handler in previous.items():
                    signal.signal(sig, handler)

        def handle_exit(self, sig: int, frame: Any) -> None:
            if self.stopped_by is not None:  # a second Ctrl-C or SIGTERM: stop waiting
                self.hurry = True
                return
            self.stopped_by = sig
            self.should_exit = True

        async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
            import asyncio

            dropper = asyncio.create_task(self._drop_connections_after_grace())
            try:
                await super().shutdown(sockets=sockets)
            finally:
                dropper.cancel()

        async def _drop_connections_after_grace(self) -> None:
            import asyncio

            loop = asyncio.get_running_loop()
            deadline = loop.time() + GRACE_S
            while loop.time() < deadline and not self.hurry:
                await asyncio.sleep(0.05)
            # The client is gone for the request: its body ends (ClientDisconnect, which the
            # routes answer quietly) and what it sends goes nowhere, so its task ends.
            for connection in list(self.server_state.connections):
                transport = getattr(connection, "transport", None)
                if transport is not None:
                    transport.abort()

    return Server(config)


def run(args: argparse.Namespace) -> int:
    """Serves until Ctrl-C or SIGTERM, then prints ``stopped (Ctrl-C)`` or ``stopped
    (SIGTERM)`` and returns 0: a signal is a server's normal end."""
    try:
        with _signals_stop():
            return _run(args)
    except _Stopped as stop:  # before the server ran
        print(f"stereodepth serve: stopped ({_SIGNAL_NAMES[stop.signum]})", flush=True)
        return 0


def _run(args: argparse.Namespace) -> int:
    # The options first (status 2, whether or not the web extra is installed).
    limits = {}
    for flag, value, scale in (
        ("--max-upload-mb", args.max_upload_mb, "max_upload_bytes"),
        ("--max-megapixels", args.max_megapixels, "max_pixels"),
    ):
        if not (value > 0 and value <= 1e4):
            raise ValueError(f"{flag} must be a number > 0 and <= 10000, got {value:g}")
        limits[scale] = max(1, int(value * 1e6))
    extra = allow_hosts(args.allow_host)
    try:
        import uvicorn

        from .app import create_app
    except ImportError as exc:
        print(
            f"stereodepth serve: error: the web page needs the 'web' extra: "
            f'pip install "stereodepth[web]" ({exc})',
            file=sys.stderr,
        )
        return 1

    sock = bind(args.host, args.port)
    url = url_of(sock)
    if not is_loopback(sock):
        bound = str(_ip_of(sock))
        shown = args.host if unbracketed(args.host) == bound else f"{args.host} ({bound})"
        print(
            f"stereodepth serve: warning: listening on {shown}, which other machines "
            "may reach; the default 127.0.0.1 keeps the page on this machine",
            file=sys.stderr,
            flush=True,
        )
    if any(entry.strip() == "*" for entry in extra):
        print(
            "stereodepth serve: warning: --allow-host '*' answers every Host header, which "
            "turns off the check against DNS rebinding: only behind a proxy that checks "
            "the Host itself",
            file=sys.stderr,
            flush=True,
        )
    print(f"stereodepth serve: the calculator is at {url}  (Ctrl+C stops it)", flush=True)
    if args.open:
        import webbrowser

        # The socket already listens, so the browser's first request waits in its backlog.
        threading.Thread(target=webbrowser.open, args=(url,), daemon=True).start()

    config = uvicorn.Config(
        create_app(allowed_hosts=allowed_hosts(args.host, sock, extra), **limits),
        log_level="warning",
        access_log=False,
        lifespan="off",
    )
    server = _server(uvicorn, config)
    try:
        server.run(sockets=[sock])
    finally:
        sock.close()
    how = _SIGNAL_NAMES.get(server.stopped_by)
    print(f"stereodepth serve: stopped{f' ({how})' if how else ''}", flush=True)
    return 0
