"""The netapp server: one shared Processor serving many robots over HTTP, Socket.IO (5G-ERA), `frames`, RTP and
WebRTC, and the cameras it pulls (FastAPI, python-socketio and the `frames` endpoint on one ASGI app).

A processor author serves a `netapp.sdk.Processor` with these (loaded on first use, so `import netapp.server` stays
cheap):

    from netapp.server import Settings, create_app, serve

    serve(MyProcessor(), port=5896)                      # uvicorn until interrupted (SIGTERM drains first)
    app = create_app(MyProcessor(), Settings(lanes=1))   # the ASGI app, to run under any ASGI server
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from netapp.server.app import create_app
    from netapp.server.runner import serve
    from netapp.server.settings import Settings

__all__ = ["Settings", "create_app", "serve"]

_HOMES = {"Settings": "netapp.server.settings", "create_app": "netapp.server.app", "serve": "netapp.server.runner"}


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'netapp.server' has no attribute {name!r}")
    return getattr(importlib.import_module(home), name)
