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


class BackgroundServer:
    """An app served by uvicorn in a thread on a free loopback port: for tests, benchmarks and local backends.

    with BackgroundServer(create_app(processor)) as server:
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
    ) -> None:
        import threading

        self._config = uvicorn.Config(
            app, host=host, port=port, log_level=log_level, lifespan="on", timeout_graceful_shutdown=2
        )
        self._server = uvicorn.Server(self._config)
        self._thread = threading.Thread(target=self._server.run, name="uvicorn", daemon=True)
        self._ready_path = ready_path
        self._timeout_s = timeout_s
        self.url = ""

    def start(self) -> BackgroundServer:
        import time

        import requests

        self._thread.start()
        deadline = time.monotonic() + self._timeout_s
        while not self._server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the server did not start")
            time.sleep(0.01)  # polling uvicorn's started flag with a deadline
        port = self._server.servers[0].sockets[0].getsockname()[1]
        self.url = f"http://{self._config.host}:{port}"
        while self._ready_path:
            try:
                if requests.get(self.url + self._ready_path, timeout=2).status_code == 200:
                    break
            except requests.RequestException:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError(f"{self.url}{self._ready_path} was not ready within {self._timeout_s} s")
            time.sleep(0.02)
        return self

    def stop(self) -> None:
        self._server.should_exit = True
        self._thread.join(timeout=10)

    def __enter__(self) -> BackgroundServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
