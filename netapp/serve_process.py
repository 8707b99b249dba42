"""Local processes on loopback: a free port, and waiting for a started server to answer (the one readiness poller:
demo, the middleware's local backend, benchmarks, tests). Needs only `requests`, so robot-side tools may use it too."""

from __future__ import annotations

import errno
import signal
import socket
import subprocess
import sys
import threading
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import asyncio


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def port_problem(host: str, port: int, option: str = "--port") -> str | None:
    """Why a server cannot listen on (host, port), as one line that says what to do; None when it can."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn does: TIME_WAIT is no conflict
        try:
            sock.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return f"port {port} on {host} is in use by another program: stop it or pick another {option}"
            if exc.errno == errno.EACCES:
                return f"no permission to listen on port {port}: pick {option} 1024 or above"
            return f"cannot listen on {host}:{port}: {exc.strerror} (check --host and {option})"
    return None


def wait_http_ok(
    url: str,
    process: subprocess.Popen | asyncio.subprocess.Process | None = None,
    timeout_s: float = 60.0,
    *,
    interval_s: float = 0.1,
    cancel: threading.Event | None = None,
) -> None:
    """Poll `url` every `interval_s` until it answers 2xx; RuntimeError if `process` exits first, the deadline passes
    or `cancel` is set. The one readiness poller of the project (local processes, servers in threads).

    `process` is a `subprocess.Popen`, or an `asyncio.subprocess.Process` when an event loop waits through a thread
    (its loop sets `returncode`; `cancel` lets a cancelled waiter end the thread)."""
    import requests  # here: `netapp serve` imports this module for port_problem, and starts ~90 ms sooner

    stop = cancel or threading.Event()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        code = process.poll() if isinstance(process, subprocess.Popen) else getattr(process, "returncode", None)
        if code is not None:
            args = getattr(process, "args", None)
            raise RuntimeError(
                f"{args[0] if isinstance(args, list) else 'the process'} exited with "
                f"code {code} before {url} answered (see its output above)"
            )
        try:
            if requests.get(url, timeout=1).ok:
                return
        except requests.RequestException:
            pass
        if stop.wait(interval_s):  # polling with a deadline
            raise RuntimeError(f"stopped waiting for {url}")
    raise RuntimeError(f"{url} did not answer within {timeout_s:.0f} s")


def serve_command(*args: str, log_level: str = "WARNING") -> list[str]:
    """The argv of `netapp serve ARGS` run by this Python (the one way tests, benchmarks and demos start one)."""
    return [sys.executable, "-m", "netapp", "--log-level", log_level, "serve", *args]


class NetAppProcess:
    """`netapp serve ARGS` in a process of its own on a free loopback port: a netapp that can be killed like a
    failed pod (tests and benchmarks). `start()` returns at once; `wait_ready()` waits for /readyz."""

    def __init__(
        self, *args: str, timeout_s: float = 90.0, log_level: str = "WARNING", advertise: bool = False
    ) -> None:
        """`advertise`: its own URL as --advertise-url too (how other replicas reach it)."""
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        own = ("--advertise-url", self.url) if advertise else ()
        self._args = serve_command(*args, "--port", str(self.port), *own, log_level=log_level)
        self._timeout_s = timeout_s
        self.process: subprocess.Popen | None = None

    def start(self) -> NetAppProcess:
        self.process = subprocess.Popen(self._args)
        return self

    def wait_ready(self) -> NetAppProcess:
        assert self.process is not None, "start() first"
        wait_http_ok(f"{self.url}/readyz", self.process, timeout_s=self._timeout_s)
        return self

    def kill(self) -> None:
        """SIGKILL, as when a node or a pod dies: no goodbye to the robots."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(timeout=10)

    def __enter__(self) -> NetAppProcess:
        return self.start().wait_ready()

    def __exit__(self, *exc) -> None:
        self.kill()
