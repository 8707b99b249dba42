"""An ASGI app served by uvicorn in a thread on a free loopback port: for tests and benchmarks."""

from __future__ import annotations

import asyncio
import concurrent.futures
import threading
import time
from collections.abc import Coroutine
from typing import Any

import uvicorn

from netapp.serve_process import wait_http_ok


class _Server(uvicorn.Server):
    """uvicorn, remembering its event loop so a test can run a coroutine of the app there."""

    loop: asyncio.AbstractEventLoop | None = None

    async def serve(self, sockets=None) -> None:
        self.loop = asyncio.get_running_loop()
        await super().serve(sockets)


class BackgroundServer:
    """with BackgroundServer(create_app(processor)) as server:
    requests.get(server.url + "/readyz")
    """

    def __init__(
        self,
        app,
        host: str = "127.0.0.1",
        port: int = 0,
        ready_path: str | None = "/readyz",
        timeout_s: float = 60.0,
        log_level: str = "warning",
        **options: Any,
    ) -> None:
        """`options`: more uvicorn.Config options, e.g. `netapp.server.runner.uvicorn_options(settings)`."""
        self._config = uvicorn.Config(
            app, host=host, port=port, log_level=log_level, lifespan="on", timeout_graceful_shutdown=2, **options
        )
        self.app = app
        self._server = _Server(self._config)
        self._thread = threading.Thread(target=self._server.run, name="uvicorn", daemon=True)
        self._ready_path = ready_path
        self._timeout_s = timeout_s
        self.url = ""

    def start(self) -> BackgroundServer:
        self._thread.start()
        deadline = time.monotonic() + self._timeout_s
        while not self._server.started:  # the port is known only once uvicorn has bound it
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the server did not start")
            time.sleep(0.01)  # polling uvicorn's started flag with a deadline
        port = self._server.servers[0].sockets[0].getsockname()[1]
        self.url = f"http://{self._config.host}:{port}"
        if self._ready_path:
            wait_http_ok(self.url + self._ready_path, timeout_s=max(0.0, deadline - time.monotonic()), interval_s=0.02)
        return self

    def call(self, coroutine: Coroutine[Any, Any, Any]) -> concurrent.futures.Future:
        """Run `coroutine` (e.g. `app.drain()`) on the server's event loop; its future, to wait on."""
        assert self._server.loop is not None, "start() the server first"
        return asyncio.run_coroutine_threadsafe(coroutine, self._server.loop)

    def stop(self) -> None:
        self._server.should_exit = True
        self._thread.join(timeout=10)

    def __enter__(self) -> BackgroundServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
