"""A netapp for a benchmark: `netapp serve` as its own process on a free loopback port, stopped on exit."""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator, Sequence

from netapp.localproc import free_port, wait_http_ok


@contextlib.contextmanager
def netapp_process(model: str, serve_args: Sequence[str] = ()) -> Iterator[tuple[subprocess.Popen, int]]:
    """Yield the running netapp and its port once /readyz answers; terminated (then killed) on exit."""
    port = free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "netapp", "--log-level", "WARNING", "serve", "--model", model, "--port", str(port)]
        + list(serve_args)
    )
    try:
        wait_http_ok(f"http://127.0.0.1:{port}/readyz", server, 120)
        yield server, port
    finally:
        server.terminate()
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
