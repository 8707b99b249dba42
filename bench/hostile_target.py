"""What `bench.hostile` attacks: a `netapp serve` process on loopback (the model's, or a processor of the bench's own,
with the failing cameras of issue 45 when asked), and what one attack's run came to."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import requests

from bench.hostile_cameras import FailingCameras
from netapp.serve_process import free_port, wait_http_ok


@dataclass
class Outcome:
    tried: int
    lost: int = 0  # attacking requests that got no answer at all
    note: str = ""


class Target:
    """A `netapp serve` process on loopback."""

    def __init__(
        self, model: str, log: Path, processor: str | None = None, cameras: FailingCameras | None = None
    ) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.host = "127.0.0.1"
        self.model, self.log_path, self.cameras = model, log, cameras
        self._log = log.open("w")
        command = [sys.executable, "-m", "netapp", "serve", "--model", model, "--port", str(self.port)]
        if processor:  # a processor of the bench's own (bench/hostile_results.py), not the model's
            command = [sys.executable, "-m", "netapp", "serve", "--processor", processor, "--port", str(self.port)]
        first = free_port()  # a few UDP ports for the RTP attacks (the netapp skips one taken meanwhile)
        command += ["--rtp-ports", f"{first}-{min(first + 7, 65535)}"]
        for source in cameras.sources() if cameras is not None else ():  # issue 45's camera attacks
            command += ["--source", source]
        self.process = subprocess.Popen(command, stdout=self._log, stderr=subprocess.STDOUT)
        wait_http_ok(f"{self.url}/readyz", self.process, timeout_s=120)

    def alive(self) -> bool:
        try:
            return self.process.poll() is None and requests.get(f"{self.url}/healthz", timeout=5).ok
        except requests.RequestException:
            return False

    def close(self) -> None:
        self.process.terminate()
        self.process.wait(10)
        self._log.close()
