"""A real load balancer in front of netapp replicas, set up like a Kubernetes Service (kube-proxy): TCP mode, a new
backend per new TCP connection (round robin), no stickiness, and the replicas' readiness probe deciding which
ones get new connections. Debian's HAProxy runs as an unprivileged process on loopback.

    with HAProxy([server_a.url, server_b.url]) as lb:
        requests.get(lb.url + "/readyz")
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from urllib.parse import urlsplit

from netapp.serve_process import free_port

INSTALL_HINT = "HAProxy is not installed: `apt-get install -y haproxy` (Debian's package; .ci/run installs it)"


def haproxy_binary() -> str | None:
    return shutil.which("haproxy") or next((p for p in ("/usr/sbin/haproxy",) if os.path.exists(p)), None)


def config_text(port: int, backends: Sequence[str], ready_path: str | None = "/readyz", check_ms: int = 200) -> str:
    """An HAProxy configuration (pure): TCP round robin over `backends` (http://host:port URLs), health-checked on
    `ready_path` every `check_ms` like a readiness probe (None: no checks, every backend always gets connections).
    """
    check = f"    option httpchk GET {ready_path}\n    http-check expect status 200\n" if ready_path else ""
    servers = "".join(
        f"    server r{i} {urlsplit(url).hostname}:{urlsplit(url).port}"
        + (f" check inter {check_ms} fall 1 rise 1" if ready_path else "")
        + "\n"
        for i, url in enumerate(backends)
    )
    return (
        "global\n    maxconn 4096\n"
        "defaults\n    mode tcp\n    timeout connect 2s\n    timeout client 60s\n    timeout server 60s\n"
        "    timeout tunnel 1h\n"
        f"frontend netapp\n    bind 127.0.0.1:{port}\n    default_backend replicas\n"
        f"backend replicas\n    balance roundrobin\n{check}{servers}"
    )


class HAProxy:
    """HAProxy on a free loopback port in front of `backends`; `url` is what robots connect to."""

    def __init__(
        self,
        backends: Sequence[str],
        ready_path: str | None = "/readyz",
        check_ms: int = 200,
        *,
        config: Callable[[int], str] | None = None,
    ) -> None:
        """`config(port)`: a configuration of the caller's, listening on `port`, instead of the Service-like one."""
        binary = haproxy_binary()
        if binary is None:
            raise FileNotFoundError(INSTALL_HINT)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self._dir = Path(tempfile.mkdtemp(prefix="netapp-haproxy-"))
        self._config = self._dir / "haproxy.cfg"
        self._config.write_text(config(self.port) if config else config_text(self.port, backends, ready_path, check_ms))
        self._binary = binary
        self._process: subprocess.Popen | None = None

    def start(self, timeout_s: float = 10.0) -> HAProxy:
        check = subprocess.run([self._binary, "-c", "-q", "-f", str(self._config)], capture_output=True, text=True)
        if check.returncode != 0:
            raise RuntimeError(f"HAProxy rejected its configuration: {check.stderr or check.stdout}")
        self._process = subprocess.Popen(
            [self._binary, "-db", "-f", str(self._config)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
        )
        deadline = time.monotonic() + timeout_s
        import socket

        while time.monotonic() < deadline:
            if self._process.poll() is not None:
                raise RuntimeError(
                    f"HAProxy exited: {self._process.stderr.read().decode() if self._process.stderr else ''}"
                )
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.5):
                    return self
            except OSError:
                time.sleep(0.02)  # polling the listening socket with a deadline
        raise RuntimeError(f"HAProxy did not listen on {self.port} within {timeout_s} s")

    def stop(self) -> None:
        if self._process is not None and self._process.poll() is None:
            self._process.send_signal(signal.SIGTERM)
            try:
                self._process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> HAProxy:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
