"""Real `netapp serve` replicas behind a real balancer set up like a Service (tests/support/haproxy.py).

    with Replicas(model_path, count=3) as replicas:
        NetAppClient(replicas.url, transport="ws")   # through HAProxy
        replicas.stop(0, signal.SIGTERM)             # drain one; replicas.start(0) brings it back

Each replica is its own process on its own loopback port, sharing a cluster key and advertising its own address,
as the operator renders them in a pod (the key from a Secret, the address from the downward API's POD_IP).
`Replicas(..., scheme="https", replica_args=[(--tls-cert ...), ...], balanced=False)`: replicas serving TLS, each
with its own arguments, reached at their own addresses (no balancer).
"""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

import requests

from netapp.serve_process import free_port, serve_command, wait_http_ok
from tests.support.haproxy import HAProxy


class Replicas:
    def __init__(
        self,
        model_path: Path,
        count: int = 2,
        *,
        drain_grace_s: float = 10.0,
        extra_args: tuple[str, ...] = (),
        scheme: str = "http",
        replica_args: Sequence[tuple[str, ...]] = (),
        balanced: bool = True,
    ) -> None:
        self.model_path = model_path
        self.drain_grace_s = drain_grace_s
        self.extra_args = extra_args
        self.replica_args = replica_args  # replica i's own arguments (after extra_args), where given
        self.ports = [free_port() for _ in range(count)]
        self.urls = [f"{scheme}://127.0.0.1:{port}" for port in self.ports]
        self._dir = Path(tempfile.mkdtemp(prefix="netapp-replicas-"))
        self.key_file = self._dir / "cluster.key"
        self.key_file.write_text(secrets.token_hex(32))
        self.processes: list[subprocess.Popen | None] = [None] * count
        self.balancer = HAProxy(self.urls, check_ms=100) if balanced else None
        self.url = self.balancer.url if self.balancer is not None else None

    def command(self, i: int) -> list[str]:
        return serve_command(
            "--model",
            str(self.model_path),
            "--port",
            str(self.ports[i]),
            "--threads",
            "1",
            "--advertise-url",
            self.urls[i],
            "--cluster-key-file",
            str(self.key_file),
            "--drain-grace",
            str(self.drain_grace_s),
            *self.extra_args,
            *(self.replica_args[i] if i < len(self.replica_args) else ()),
        )

    def spawn(self, i: int) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        with open(self.log_path(i), "a") as log:  # the child keeps its own copy of the descriptor
            self.processes[i] = subprocess.Popen(self.command(i), env=env, stderr=log, stdout=log)

    def log_path(self, i: int) -> Path:
        return self._dir / f"replica-{i}.log"

    def log(self, i: int, tail: int = 3000) -> str:
        """The end of what replica `i` logged (all its runs), for an assertion's message."""
        return self.log_path(i).read_text()[-tail:] if self.log_path(i).exists() else ""

    def wait_ready(self, i: int, timeout_s: float = 60.0) -> None:
        wait_http_ok(self.urls[i] + "/readyz", self.processes[i], timeout_s=timeout_s, interval_s=0.05)

    def start(self, i: int | None = None) -> Replicas:
        """Start replica `i` (all of them when None) and wait until it is ready and the balancer sees it."""
        indexes = range(len(self.ports)) if i is None else [i]
        for j in indexes:
            self.spawn(j)
        for j in indexes:
            self.wait_ready(j)
        return self

    def stop(self, i: int, sig: int = signal.SIGTERM) -> subprocess.Popen:
        """Send `sig` to replica `i`; returns its process (wait on it for the exit)."""
        process = self.processes[i]
        assert process is not None
        process.send_signal(sig)
        return process

    def kill_all(self) -> None:
        for process in self.processes:
            if process is not None and process.poll() is None:
                process.kill()
                process.wait(timeout=10)

    def metric(self, i: int, sample: str) -> float:
        """The sum of replica `i`'s samples that start with `sample` (a name, or a name and labels)."""
        text = requests.get(self.urls[i] + "/metrics", timeout=5).text
        return sum(float(line.rsplit(" ", 1)[1]) for line in text.splitlines() if line.startswith(sample))

    def metrics(self, sample: str) -> list[float]:
        """`metric` of every replica that is running."""
        return [self.metric(i, sample) if self.running(i) else 0.0 for i in range(len(self.ports))]

    def running(self, i: int) -> bool:
        process = self.processes[i]
        return process is not None and process.poll() is None

    def __enter__(self) -> Replicas:
        try:
            self.start()
            if self.balancer is not None:
                self.balancer.start()
        except BaseException:
            self.kill_all()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        if self.balancer is not None:
            self.balancer.stop()
        self.kill_all()
        shutil.rmtree(self._dir, ignore_errors=True)
