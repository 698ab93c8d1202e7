"""The web app's Host-header check, against DNS rebinding: :class:`HostCheck`.

A page of another site whose name its DNS then points at 127.0.0.1 (DNS rebinding) runs in
the browser as that site's, so the browser lets it read a local server's answers; its
requests still carry its own name in the Host header. :func:`stereodepth.web.app.create_app`
puts this check in front of every route, so the app refuses such requests under whichever
server runs it (``stereodepth serve``, ``uvicorn --factory``, or mounted in another app).

The hosts answered (``create_app(allowed_hosts=...)``: the whole list, which replaces the
default; to answer another name as well, keep the default's in it:
``create_app(allowed_hosts=[*LOOPBACK_HOSTS, "depth.lab:8080"])``), each an entry of

- a name or IP address (an IPv6 one with or without its brackets): that name at the port the
  server listens on (the ASGI scope's ``server``; when the server does not say, at any port);
  a name of other than ASCII characters as its IDNA (punycode) form, which is what a browser
  sends (``ünïcode.local`` is ``xn--ncode-cta3g.local``; Python's ``idna`` codec, IDNA 2003);
- ``name:port``: that name at that port only (a server behind a port mapping, e.g. Docker's
  ``-p 8080:8000``, is reached at a port that is not its own);
- ``0.0.0.0`` or ``::`` (optionally with ``:port``): any IP address, for a server on every
  interface (a page loaded from an IP address is the server's own: rebinding needs a name);
- ``*``: every Host, no check (only behind a proxy that checks the Host itself).

``stereodepth serve`` takes the same entries with ``--allow-host`` (repeated for more), which
add to the names it answers (the default's, its ``--host`` and the address it bound).

The default, :data:`LOOPBACK_HOSTS`: ``localhost``, ``127.0.0.1`` and ``[::1]``. Always
answered as well: the IP address the connection came in on, as the server reports it (the
address the client typed). A Host without a port means 80 (443 over https); names match
whatever their case.
"""

from __future__ import annotations

import ipaddress
import json
import re
from collections.abc import Iterable
from typing import Any

__all__ = ["ANY_HOST", "LOOPBACK_HOSTS", "AllowedHosts", "HostCheck"]

#: The hosts a local server answers by default (also ``stereodepth.web.LOOPBACK_HOSTS``):
#: ``create_app(allowed_hosts=[*LOOPBACK_HOSTS, "name:port"])`` answers another name too.
LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "[::1]")
#: The entry of ``allowed_hosts`` that turns the check off.
ANY_HOST = "*"
_ANY_ADDRESS = ""  # an entry's name for "any IP address"
# A host name that a refusal may show as an entry to type (no characters a shell would read).
_PLAIN_NAME = re.compile(r"[a-z0-9_][a-z0-9_.-]*")


def _split_host(value: str) -> tuple[str, int | None] | None:
    """A Host header's name (lower case, without the brackets of an IPv6 address) and port
    (None: none given), or None when it is not of that form."""
    if value.startswith("["):
        name, sep, rest = value[1:].partition("]")
        if not sep:
            return None
    else:
        name, sep, rest = value.partition(":")
        rest = sep + rest
    if rest == "":
        return name.lower(), None
    digits = rest[1:]
    if not (rest.startswith(":") and digits.isascii() and digits.isdigit() and len(digits) <= 5):
        return None
    return name.lower(), int(digits)


def _ip(name: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        return ipaddress.ip_address(name)
    except ValueError:
        return None


def _canonical(name: str) -> str:
    """An IP address in its one spelling (``0:0:0:0:0:0:0:1`` is ``::1``); a name as is."""
    ip = _ip(name)
    return name if ip is None else str(ip)


def _shown(name: str, port: int | None) -> str:
    shown = f"[{name}]" if ":" in name else name
    return shown if port is None else f"{shown}:{port}"


class _BadEntry(ValueError):
    """An entry of ``allowed_hosts`` that is not a host name or IP address (with an optional
    ``:port``) nor ``"*"``; ``why`` adds the reason where there is one (IDNA's), for the
    callers that word the message for their own option (serve's ``--allow-host``)."""

    def __init__(self, entry: str, why: str) -> None:
        self.entry, self.why = entry, why
        super().__init__(
            "allowed_hosts must hold host names or IP addresses, each optionally with "
            f":port, or '*', got {entry[:60]!r}{why}"
        )


class AllowedHosts:
    """The Host header values a server answers (see the module's doc for the entries).
    Raises TypeError for ``hosts`` that is not a list of strings (a single string too: give
    ``["name"]``), ValueError naming an entry that is not a host name or IP address, either
    optionally with ``:port`` (1 to 65535), or ``"*"`` (no wildcards in names; a name of
    other than ASCII characters that the ``idna`` codec cannot encode)."""

    def __init__(self, hosts: Iterable[str] | None = None) -> None:
        if hosts is None:
            hosts = LOOPBACK_HOSTS
        elif isinstance(hosts, (str, bytes)) or not isinstance(hosts, Iterable):
            raise TypeError(
                f"allowed_hosts must be a list of host names, got {hosts!r:.60}"
                + (f" (give [{hosts!r}])" if isinstance(hosts, str) else "")
            )
        entries: list[tuple[str, int | None]] = []
        self.any_host = False
        for entry in hosts:
            if not isinstance(entry, str):
                raise TypeError(f"allowed_hosts must hold strings, got {entry!r:.60}")
            if entry.strip() == ANY_HOST:
                self.any_host = True
                continue
            text = entry.strip()
            # A bare IPv6 address ("::1") has colons of its own: no port.
            parts = (text, None) if _ip(text) is not None else _split_host(text)
            name = "" if parts is None else parts[0]
            why = ""
            if not name.isascii():
                # A browser sends the name's IDNA (punycode) form: "xn--...".
                try:
                    name = name.encode("idna").decode("ascii").lower()
                except UnicodeError as exc:
                    why = f" (IDNA cannot encode it: {exc.__cause__ or exc})"
                    name = ""
            bad_port = parts is not None and parts[1] is not None and not 0 < parts[1] < 65536
            # "*.example.com" or "a,b" would be names no Host has: refused, not never matched
            if (
                parts is None
                or not name
                or bad_port
                or any(c in name for c in "/?#@*, \t[]")
                or not name.isprintable()
            ):
                raise _BadEntry(entry, why)
            ip = _ip(name)
            name = _ANY_ADDRESS if ip is not None and ip.is_unspecified else _canonical(name)
            if (name, parts[1]) not in entries:
                entries.append((name, parts[1]))
        #: (name, port): a name ("" for any IP address) and its port (None: the server's).
        self.entries = tuple(entries)

    def allows(
        self,
        value: str | None,
        port: int | None,
        address: str | None = None,
        default_port: int = 80,
    ) -> bool:
        """Whether a request with this Host header (None: none) is answered by a server
        listening on ``port`` (None: unknown), reached at IP ``address``."""
        if self.any_host:
            return True
        if value is None:
            return False
        parts = _split_host(value)
        if parts is None:
            return False
        name, got = parts
        if not name:
            return False
        name = _canonical(name)
        if got is None:
            got = default_port
        for entry, want in self._with(address):
            want = port if want is None else want
            if want is not None and got != want:
                continue
            if entry == name or (entry == _ANY_ADDRESS and _ip(name) is not None):
                return True
        return False

    def _with(self, address: str | None) -> tuple[tuple[str, int | None], ...]:
        """The entries, with the IP address the connection came in on."""
        ip = None if address is None else _ip(address)
        if ip is None or ip.is_unspecified:
            return self.entries
        extra = (str(ip), None)
        return self.entries if extra in self.entries else (*self.entries, extra)

    def expected(self, port: int | None, address: str | None = None) -> str:
        """The hosts answered, in words: ``localhost:8000, 127.0.0.1:8000 or [::1]:8000``."""
        entries = self._with(address)
        anywhere = [p if p is not None else port for n, p in entries if n == _ANY_ADDRESS]
        names = [
            _shown(n, p if p is not None else port)
            for n, p in entries
            if n != _ANY_ADDRESS
            # an address that "any IP address" at its port already covers
            and not (_ip(n) is not None and (p if p is not None else port) in anywhere)
        ]
        names += ["an IP address" if p is None else f"an IP address with :{p}" for p in anywhere]
        if len(names) < 2:
            return "".join(names)
        return ", ".join(names[:-1]) + " or " + names[-1]


# create_app's allowed_hosts is the whole list: the hint keeps the loopback names in it.
_LOOPBACK_FROM = " with LOOPBACK_HOSTS from stereodepth.web"


def _hint(value: str | None, default_port: int) -> str:
    """How to have this Host answered too: the entry that names it (its name with the port it
    means, a Host without a port meaning ``default_port``), when it is a plain host name or IP
    address; else the form of one. ``--allow-host`` adds to the names answered, while
    ``allowed_hosts`` is all of them, so the hint shows it with :data:`LOOPBACK_HOSTS`."""
    parts = None if value is None or len(value) > 60 else _split_host(value)
    if parts is not None and parts[0] and (_ip(parts[0]) or _PLAIN_NAME.fullmatch(parts[0])):
        entry = _shown(parts[0], default_port if parts[1] is None else parts[1])
        return (
            f"to answer it: stereodepth serve --allow-host {entry}, "
            f"or create_app(allowed_hosts=[*LOOPBACK_HOSTS, {entry!r}]){_LOOPBACK_FROM}"
        )
    return (
        "to answer a name: stereodepth serve --allow-host NAME[:PORT], "
        f"or create_app(allowed_hosts=[*LOOPBACK_HOSTS, ...]){_LOOPBACK_FROM}"
    )


def _json_400(msg: str) -> tuple[dict[str, Any], bytes]:
    body = json.dumps(
        {"detail": [{"loc": ["header", "host"], "msg": msg, "type": "invalid_host"}]}
    ).encode()
    start = {
        "type": "http.response.start",
        "status": 400,
        "headers": [
            (b"content-type", b"application/json"),
            (b"content-length", str(len(body)).encode()),
            (b"connection", b"close"),
        ],
    }
    return start, body


class HostCheck:
    """ASGI middleware: refuses, with 400 and a one-line reason at ``["header", "host"]``
    (which ends with the ``--allow-host`` or ``allowed_hosts`` entry that would answer it),
    every request whose Host header is not one of ``allowed`` (an :class:`AllowedHosts`, or
    its entries; default :data:`LOOPBACK_HOSTS`), before the app reads its body; a WebSocket
    is closed with 1008. Raises what :class:`AllowedHosts` raises for bad entries."""

    def __init__(self, app: Any, allowed: AllowedHosts | Iterable[str] | None = None) -> None:
        self.app = app
        self.allowed = allowed if isinstance(allowed, AllowedHosts) else AllowedHosts(allowed)

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        values = [v.decode("latin-1") for k, v in scope.get("headers", ()) if k == b"host"]
        value = values[0] if len(values) == 1 else None
        server = scope.get("server") or (None, None)
        address = server[0] if isinstance(server[0], str) else None
        port = server[1] if isinstance(server[1], int) else None
        default_port = 443 if scope.get("scheme") in ("https", "wss") else 80
        if self.allowed.allows(value, port, address, default_port):
            await self.app(scope, receive, send)
            return
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008})
            return
        if not values:
            got = "no Host header"
        elif len(values) > 1:
            got = f"{len(values)} Host headers"
        else:
            got = f"Host {values[0][:60]!r}"
        msg = (
            f"the Host header must name this server ({self.allowed.expected(port, address)}), "
            f"got {got}: a page of another site cannot use it "
            f"({_hint(value, default_port)})"
        )
        start, body = _json_400(msg)
        await send(start)
        await send({"type": "http.response.body", "body": body})
