"""Running an app with uvicorn."""

from __future__ import annotations

import uvicorn

from netapp.protocol import DEFAULT_PORT
from netapp.sdk.processor import Processor
from netapp.server.app import create_app
from netapp.server.settings import Settings


def run_server(
    processor: Processor,
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    settings: Settings | None = None,
    log_level: str = "info",
) -> None:
    settings = settings or Settings()
    app = create_app(processor, settings)
    uvicorn.run(
        app,
        host=host,
        port=port,
        log_level=log_level,
        ws_max_size=settings.transport_limit_bytes,
        timeout_graceful_shutdown=5,
    )
