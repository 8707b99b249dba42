"""Running an app with uvicorn."""

from __future__ import annotations

import uvicorn

from netapp.sdk.processor import Processor
from netapp.server.app import create_app
from netapp.server.settings import Settings


def run_server(processor: Processor, host: str = "127.0.0.1", port: int = 5896, settings: Settings | None = None,
               log_level: str = "info") -> None:  # fmt: skip
    app = create_app(processor, settings)
    uvicorn.run(app, host=host, port=port, log_level=log_level, ws_max_size=_ws_limit(settings), timeout_graceful_shutdown=5)


def _ws_limit(settings: Settings | None) -> int:
    return (settings or Settings()).max_payload_bytes + 64 * 1024
