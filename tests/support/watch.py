"""What the hostile tests and bench/hostile.py watch while attacking a netapp: a well-behaved robot streaming beside
the attack, and the netapp's resident memory."""

from __future__ import annotations

import itertools
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import requests

from tests.support.images import make_jpeg


@dataclass
class Window:
    """The good robot's results during one stretch of time."""

    results: int
    failures: int  # answers other than a result (superseded frames excepted): each one is a lost frame
    longest_gap_s: float  # longest stretch without a result, window edges included
    p95_latency_s: float


class GoodRobot:
    """A robot that sends a JPEG over HTTP with ?wait=true every `period_s`, in a thread, and records when each
    result came back and how long it took. `own_process`: it runs in a process of its own (`python -m
    tests.support.watch`), as a robot on another machine would, so the attacker's threads beside it in this process
    (its GIL) do not delay it: what it sees is the netapp's doing."""

    def __init__(self, url: str, period_s: float = 0.05, own_process: bool = False) -> None:
        self.url = url
        self.period_s = period_s
        self._lock = threading.Lock()
        self._results: list[tuple[float, float]] = []  # (arrival, latency), monotonic seconds (system-wide)
        self._failures: list[float] = []
        self._stop = threading.Event()
        self._child: subprocess.Popen | None = None
        if own_process:
            command = [sys.executable, "-m", "tests.support.watch", url, str(period_s)]
            self._child = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        else:
            self._http = requests.Session()
            self._session_id = self._http.post(f"{url}/register", json={"robot_id": "good"}, timeout=10).json()[
                "session_id"
            ]
            self._jpeg = make_jpeg(320, 240)
        self._thread = threading.Thread(
            target=self._run if self._child is None else self._read_child, name="good-robot", daemon=True
        )

    def __enter__(self) -> GoodRobot:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._child is not None:
            assert self._child.stdin is not None
            self._child.stdin.close()  # its signal to stop
            self._child.wait(30)
        self._thread.join(30)

    def _run(self) -> None:
        headers = {"X-Session-Id": self._session_id, "Content-Type": "image/jpeg"}
        while not self._stop.is_set():
            sent = time.monotonic()
            try:
                r = self._http.post(f"{self.url}/send_image?wait=true", data=self._jpeg, headers=headers, timeout=30)
                ok = r.status_code == 200
                superseded = r.status_code == 409
            except requests.RequestException:
                ok = superseded = False
            now = time.monotonic()
            self._record(ok, superseded, now, now - sent)
            self._stop.wait(max(0.0, self.period_s - (now - sent)))

    def _record(self, ok: bool, superseded: bool, now: float, latency: float) -> None:
        with self._lock:
            if ok:
                self._results.append((now, latency))
            elif not superseded:
                self._failures.append(now)

    def _read_child(self) -> None:
        """The robot in its own process: each of its lines is one answer (`_ReportingRobot`)."""
        assert self._child is not None and self._child.stdout is not None
        for line in self._child.stdout:
            ok, superseded, now, latency = line.split()
            self._record(ok == "1", superseded == "1", float(now), float(latency))

    def window(self, start: float, end: float | None = None) -> Window:
        """The results between `start` and `end` (monotonic; default now)."""
        end = time.monotonic() if end is None else end
        with self._lock:
            inside = [(t, lat) for t, lat in self._results if start <= t <= end]
            failures = sum(1 for t in self._failures if start <= t <= end)
        edges = [start] + [t for t, _ in inside] + [end]
        latencies = sorted(lat for _, lat in inside)
        p95 = latencies[min(len(latencies) - 1, int(0.95 * len(latencies)))] if latencies else float("inf")
        return Window(len(inside), failures, max(b - a for a, b in itertools.pairwise(edges)), p95)

    def wait_for_results(self, count: int, timeout_s: float = 30.0) -> None:
        """Until `count` results arrived (the robot is streaming), polled with a deadline."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                if len(self._results) >= count:
                    return
            time.sleep(0.05)
        raise AssertionError(f"the good robot got fewer than {count} results in {timeout_s} s")


def rss_bytes(pid: int, peak: bool = False) -> int:
    """A process's resident memory now (VmRSS), or its peak since it started (VmHWM), from /proc."""
    field = "VmHWM:" if peak else "VmRSS:"
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field):
            return int(line.split()[1]) * 1024
    raise RuntimeError(f"no {field} in /proc/{pid}/status")


class PeakRss:
    """Samples a process's RSS every `period_s` in a thread: the peak within a stretch of time (VmHWM only
    knows the peak since the process started)."""

    def __init__(self, pid: int, period_s: float = 0.02) -> None:
        self.pid, self.period_s = pid, period_s
        self.peak = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rss", daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.peak = max(self.peak, rss_bytes(self.pid))
            except (OSError, RuntimeError):
                return
            self._stop.wait(self.period_s)

    def __enter__(self) -> PeakRss:
        self.peak = rss_bytes(self.pid)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)


class _ReportingRobot(GoodRobot):
    """The good robot in its own process: each answer goes to stdout as one line, for `GoodRobot._read_child`."""

    def _record(self, ok: bool, superseded: bool, now: float, latency: float) -> None:
        print(int(ok), int(superseded), now, latency, flush=True)


if __name__ == "__main__":  # GoodRobot(own_process=True): until stdin closes
    with _ReportingRobot(sys.argv[1], float(sys.argv[2])):
        sys.stdin.read()
