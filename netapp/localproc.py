"""Local processes on loopback: a free port, and waiting for a started server to answer (demo, local backend,
benchmarks, tests). Needs only `requests`, so robot-side tools may use it too."""

from __future__ import annotations

import errno
import socket
import subprocess
import time

import requests


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
    url: str, process: subprocess.Popen | None = None, timeout_s: float = 60.0, *, interval_s: float = 0.1
) -> None:
    """Poll `url` every `interval_s` until it answers 2xx; RuntimeError if `process` exits first or the deadline
    passes. The one readiness poller of the project (local processes, servers in threads)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process is not None and process.poll() is not None:
            raise RuntimeError(
                f"{process.args[0] if isinstance(process.args, list) else 'the process'} exited with "
                f"code {process.returncode} before {url} answered (see its output above)"
            )
        try:
            if requests.get(url, timeout=1).ok:
                return
        except requests.RequestException:
            pass
        time.sleep(interval_s)  # polling with a deadline
    raise RuntimeError(f"{url} did not answer within {timeout_s:.0f} s")
