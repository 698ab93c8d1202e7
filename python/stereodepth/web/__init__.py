"""The calculator as a local web page: ``stereodepth serve``.

- :mod:`stereodepth.web.app`: the FastAPI app (``create_app()``): the page, its static files
  and plotly.js from the installed plotly package (offline), and the JSON API ``/api/calc``
  with its OpenAPI schema at ``/openapi.json``.
- :mod:`stereodepth.web.host`: the app's Host-header check (against DNS rebinding), which
  ``create_app(allowed_hosts=...)`` sets (the whole list); by default :data:`LOOPBACK_HOSTS`,
  localhost, 127.0.0.1 and [::1], which ``allowed_hosts=[*LOOPBACK_HOSTS, "name:port"]``
  keeps.
- :mod:`stereodepth.web.serve`: the ``serve`` subcommand (uvicorn on 127.0.0.1).

Needs the ``web`` extra: ``pip install "stereodepth[web]"``. This package imports nothing
heavy itself, so that the command line stays quick.
"""

from __future__ import annotations

from .host import LOOPBACK_HOSTS  # the standard library only

__all__ = ["LOOPBACK_HOSTS"]
