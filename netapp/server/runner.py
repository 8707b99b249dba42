"""Running an app with uvicorn; SIGTERM drains the replica first (its robots move) and then stops it."""

from __future__ import annotations

import asyncio
import logging
import signal
import sys
from collections.abc import Awaitable, Callable
from types import FrameType
from typing import Any

import cv2
import uvicorn

from netapp.protocol import DEFAULT_PORT
from netapp.sdk.processor import Processor
from netapp.serve_process import port_problem
from netapp.server.allocator import set_malloc_thresholds
from netapp.server.app import create_app
from netapp.server.http.head_deadline import bounded_http_protocol
from netapp.server.settings import Settings

log = logging.getLogger(__name__)


class DrainingServer(uvicorn.Server):
    """uvicorn, where the first SIGTERM runs `drain` before the usual shutdown. SIGINT (Ctrl-C) and a second
    SIGTERM stop at once, as plain uvicorn does."""

    def __init__(self, config: uvicorn.Config, drain: Callable[[], Awaitable[None]]) -> None:
        super().__init__(config)
        self._drain = drain
        self._loop: asyncio.AbstractEventLoop | None = None
        self._draining: asyncio.Task | None = None

    async def serve(self, sockets=None) -> None:
        self._loop = asyncio.get_running_loop()
        await super().serve(sockets)

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        if sig == signal.SIGTERM and self._loop is not None and self._draining is None and not self.should_exit:
            self._loop.call_soon_threadsafe(self._start_draining)
            return
        super().handle_exit(sig, frame)

    def _start_draining(self) -> None:
        if self._draining is None:
            self._draining = asyncio.ensure_future(self._drain_then_exit())

    async def _drain_then_exit(self) -> None:
        try:
            await self._drain()
        except Exception:
            log.exception("draining failed; stopping now")
        finally:
            self.should_exit = True


GIL_SWITCH_S = 0.0005


def serve(
    processor: Processor,
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    settings: Settings | None = None,
    log_level: str = "info",
    tls_cert: str | None = None,
    tls_key: str | None = None,
) -> None:
    """Run `processor` as a netapp with uvicorn until stopped (SIGTERM drains first); with `tls_cert` and `tls_key`
    (PEM files) over HTTPS and WSS only. A port it cannot listen on ends the program with one line and exit code 2,
    as `netapp serve` does."""
    problem = port_problem(host, port, "port")
    if problem:  # before the app is built: the answer comes at once, and not as uvicorn's traceback and exit 3
        print(f"netapp: {problem}", file=sys.stderr)
        raise SystemExit(2)
    settings = settings or Settings()
    # A thread that wants the GIL waits up to this long for the one holding it (5 ms by default); on every frame
    # the event loop and the inference thread hand it to each other (docs/benchmarks.md#profile).
    sys.setswitchinterval(GIL_SWITCH_S)
    set_malloc_thresholds()
    cv2.setNumThreads(settings.opencv_threads)
    log.info("OpenCV: %d thread(s) for one picture's decoding and resizing", cv2.getNumThreads())
    app = create_app(processor, settings)
    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level=log_level,
        timeout_graceful_shutdown=5,
        ssl_certfile=tls_cert,
        ssl_keyfile=tls_key,
        **uvicorn_options(settings),
    )
    DrainingServer(config, app.drain).run()


def uvicorn_options(settings: Settings) -> dict[str, Any]:
    """The uvicorn options that bound what connections may hold (docs/security.md#limits)."""
    return {
        "http": bounded_http_protocol(settings.head_timeout_s),
        "ws_max_size": settings.transport_limit_bytes,
        "timeout_keep_alive": settings.keep_alive_s,
        "limit_concurrency": settings.max_connections,
    }
