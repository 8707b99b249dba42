"""Running an app with uvicorn; SIGTERM drains the replica first (its robots move) and then stops it."""

from __future__ import annotations

import asyncio
import ctypes
import logging
import os
import signal
import sys
from collections.abc import Awaitable, Callable
from types import FrameType
from typing import Any

import uvicorn

from netapp.protocol import DEFAULT_PORT
from netapp.sdk.processor import Processor
from netapp.server.app import create_app
from netapp.server.http.head_deadline import timed_h11_protocol
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
# glibc's malloc maps a block of this size or more on its own and unmaps it when freed. Its default threshold, 128 KiB,
# rises to the size of each mapped block freed (up to 32 MiB): after the first 4K picture (25 MB) is freed, pictures
# and packets of megabytes come from the heap and the per-thread arenas, which keep their high-water mark, spread over
# every thread that ever decoded, converted or received one (docs/benchmarks.md#the-floods-measured-again-issue-22).
# Setting it also stops that rise. glibc's own MALLOC_MMAP_THRESHOLD_, when set, wins.
MALLOC_MMAP_THRESHOLD_BYTES = 1024 * 1024
_M_MMAP_THRESHOLD = -3  # mallopt's parameter number (malloc.h)


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
    (PEM files) over HTTPS and WSS only."""
    settings = settings or Settings()
    # A thread that wants the GIL waits up to this long for the one holding it (5 ms by default); on every frame
    # the event loop and the inference thread hand it to each other (docs/benchmarks.md#profile).
    sys.setswitchinterval(GIL_SWITCH_S)
    fix_mmap_threshold()
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
        "http": timed_h11_protocol(settings.head_timeout_s),
        "ws_max_size": settings.transport_limit_bytes,
        "timeout_keep_alive": settings.keep_alive_s,
        "limit_concurrency": settings.max_connections,
        # h11 refuses a request head over this (431) instead of buffering it: uvicorn's default is 16 KiB.
        "h11_max_incomplete_event_size": 16 * 1024,
    }


def fix_mmap_threshold(threshold: int = MALLOC_MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's mmap threshold at `threshold` (see MALLOC_MMAP_THRESHOLD_BYTES), logged; False where it was not
    set (another C library, or MALLOC_MMAP_THRESHOLD_ in the environment)."""
    if os.environ.get("MALLOC_MMAP_THRESHOLD_"):
        log.info("malloc: MALLOC_MMAP_THRESHOLD_=%s from the environment", os.environ["MALLOC_MMAP_THRESHOLD_"])
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError, TypeError):  # no C library to look in (Windows), or no mallopt (macOS)
        return False
    if mallopt(_M_MMAP_THRESHOLD, threshold) != 1:
        return False
    log.info("malloc: blocks of %d bytes and more mapped on their own (M_MMAP_THRESHOLD)", threshold)
    return True
