"""A real server in a child process for the web tests (``stereodepth serve``, uvicorn): started,
waited for until it prints where it listens, stopped by a signal."""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import stereodepth

#: Where this process imported stereodepth from (the source tree with an in-place build, or
#: site-packages after `pip install .`), for the child processes to import the same.
PYTHON_DIR = Path(stereodepth.__file__).resolve().parents[1]
START_TIMEOUT_S = 30


class ServerProcess:
    """``python args...`` in a subprocess, stereodepth importable from :data:`PYTHON_DIR` (and
    ``extra_path``), ``env`` added to the environment. The lines of its ``stream`` ("stdout"
    or "stderr") are read on a thread into :attr:`lines` (a queue) and :attr:`log`; it counts
    as started at the first line that ``ready`` (a regular expression) finds in, kept as
    :attr:`ready` (the match) and :attr:`first_line`. Raises AssertionError, the process
    killed, when it ends or prints no such line within ``timeout`` seconds."""

    #: Where it listens, for the servers that say (set by :func:`serve` and the tests).
    port: int
    url: str

    def __init__(
        self,
        args: Sequence[str],
        *,
        ready: str,
        stream: str = "stdout",
        env: dict[str, str] | None = None,
        extra_path: Path | None = None,
        timeout: float = START_TIMEOUT_S,
    ) -> None:
        pythonpath = [str(PYTHON_DIR)] + ([str(extra_path)] if extra_path else [])
        self.proc = subprocess.Popen(
            [sys.executable, *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(pythonpath), **(env or {})},
        )
        self.stream = stream
        source = getattr(self.proc, stream)
        assert source is not None
        self.lines: queue.Queue[str] = queue.Queue()
        self.log: list[str] = []

        def read() -> None:
            for line in source:
                self.log.append(line)
                self.lines.put(line)

        self.reader = threading.Thread(target=read, daemon=True)
        self.reader.start()
        deadline = time.monotonic() + timeout
        while True:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                self.kill()
                raise AssertionError(
                    f"{args} did not start in {timeout} s: {''.join(self.log)}"
                ) from None
            found = re.search(ready, line)
            if found:
                self.ready = found
                self.first_line = line
                return
            if self.proc.poll() is not None and self.lines.empty():
                self.kill()
                raise AssertionError(f"{args} ended: {''.join(self.log)}")

    def stop(
        self, sig: int = signal.SIGINT, timeout: float = 15
    ) -> tuple[int | None, float, str, str]:
        """Sends ``sig`` (if it still runs); the exit status (None: still running after
        ``timeout`` s, then killed), the seconds it took, the rest of the read stream (what
        came after the line that started it) and the whole other stream; the pipes are
        closed then."""
        t0 = time.monotonic()
        code: int | None
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                code = self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                code = None
                self.proc.kill()
                self.proc.wait()
        else:
            code = self.proc.returncode
        took = time.monotonic() - t0
        other = self.proc.stderr if self.stream == "stdout" else self.proc.stdout
        assert other is not None
        other_text = other.read()
        self.reader.join(timeout=10)  # it ends at the end of the server's output
        rest = []
        while not self.lines.empty():
            rest.append(self.lines.get())
        self.kill()  # closes the pipes
        return code, took, "".join(rest), other_text

    def kill(self) -> None:
        """Ends the process if it still runs, and closes its pipes."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.reader.join(timeout=10)
        for pipe in (self.proc.stdout, self.proc.stderr):
            if pipe is not None:
                pipe.close()


#: ``python -c`` for ``stereodepth serve`` with host names of the test's own (``sys.argv[1]``,
#: JSON: name -> the address, or addresses, its look-up gives; see :func:`serve`).
_SERVE_WITH_NAMES = """
import json, socket, sys
names = json.loads(sys.argv.pop(1))
real = socket.getaddrinfo
def getaddrinfo(host, *args, **kwargs):
    found = names.get(host.lower() if isinstance(host, str) else host)
    if found is None:
        return real(host, *args, **kwargs)
    return [info for address in found for info in real(address, *args, **kwargs)]
socket.getaddrinfo = getaddrinfo
from stereodepth.cli import main
sys.exit(main(sys.argv[1:]))
"""


def serve(
    *args: str, env: dict[str, str] | None = None, names: dict[str, list[str]] | None = None
) -> ServerProcess:
    """``stereodepth serve args...``, started once it prints its URL (``ready`` group 1 the
    host, group 2 the port, group 0 the URL with its final slash). ``names``: host names that
    resolve, in the server's process only, to these addresses (as /etc/hosts would map them;
    other names as usual)."""
    command = ["-m", "stereodepth.cli"]
    if names is not None:
        command = ["-c", _SERVE_WITH_NAMES, json.dumps(names)]
    server = ServerProcess([*command, "serve", *args], ready=r"http://([^\s/]+):(\d+)/", env=env)
    server.port = int(server.ready.group(2))
    server.url = server.ready.group(0)
    return server
