"""`netapp serve` in a process of its own on a loopback port: a netapp that a test can kill like a failed pod."""

from __future__ import annotations

import signal
import subprocess
import sys

from netapp.localproc import free_port, wait_http_ok


class NetAppProcess:
    def __init__(self, *args: str, timeout_s: float = 90.0) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self._args = [sys.executable, "-m", "netapp", "--log-level", "WARNING", "serve", *args]
        self._args += ["--port", str(self.port)]
        self._timeout_s = timeout_s
        self.process: subprocess.Popen | None = None

    def start(self) -> NetAppProcess:
        self.process = subprocess.Popen(self._args)
        return self

    def wait_ready(self) -> NetAppProcess:
        assert self.process is not None
        wait_http_ok(f"{self.url}/readyz", self.process, timeout_s=self._timeout_s)
        return self

    def kill(self) -> None:
        """SIGKILL, as when a node or pod dies: no goodbye to the robots."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(timeout=10)

    def __enter__(self) -> NetAppProcess:
        return self.start().wait_ready()

    def __exit__(self, *exc) -> None:
        self.kill()
