"""Running an app with uvicorn."""

from __future__ import annotations

from typing import Any

import uvicorn

from netapp.protocol import DEFAULT_PORT
from netapp.sdk.processor import Processor
from netapp.server.app import create_app
from netapp.server.http_protocol import timed_h11_protocol
from netapp.server.settings import Settings


def run_server(
    processor: Processor,
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    settings: Settings | None = None,
    log_level: str = "info",
    tls_cert: str | None = None,
    tls_key: str | None = None,
) -> None:
    """Serve until stopped; with `tls_cert` and `tls_key` (PEM files) over HTTPS and WSS only."""
    settings = settings or Settings()
    app = create_app(processor, settings)
    uvicorn.run(
        app,
        host=host,
        port=port,
        log_level=log_level,
        timeout_graceful_shutdown=5,
        ssl_certfile=tls_cert,
        ssl_keyfile=tls_key,
        **uvicorn_options(settings),
    )


def uvicorn_options(settings: Settings) -> dict[str, Any]:
    """The uvicorn options that bound what connections may hold (README: "Limits and security")."""
    return {
        "http": timed_h11_protocol(settings.head_timeout_s),
        "ws_max_size": settings.transport_limit_bytes,
        "timeout_keep_alive": settings.keep_alive_s,
        "limit_concurrency": settings.max_connections,
        # h11 refuses a request head over this (431) instead of buffering it: uvicorn's default is 16 KiB.
        "h11_max_incomplete_event_size": 16 * 1024,
    }
