"""An unmodified era-5g-client robot for the benchmarks: `NetAppClientBase` as a 5G-ERA robot uses it (register,
then `send_image` with JPEG at the camera's rate, results on the `results` callback), summed up in the same fields
as `netapp.client.stats.ClientStats.summary`, so `bench.robots` can put it in the same table as NetAppClient robots.

It sends every frame (the client has no pacing; its own back-pressure refuses a frame, `BackPressureException`, when
its Socket.IO queue is full: the robot drops it and goes on) and the netapp takes the newest one at each turn:
results are what the robot got, the rest were superseded.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable

import numpy as np

DRAIN_S = 2.0  # after the last frame, how long the robot waits for the results still on their way


class Era5gRobot:
    """One era-5g-client robot: `connect()` registers (INIT), `stream(frames, fps, duration_s)` sends and sums up,
    `close()` disconnects. `arrivals` gets the wall-clock time of each result."""

    def __init__(self, url: str, robot_id: str, arrivals: list[float]) -> None:
        from era_5g_client.client_base import NetAppClientBase
        from era_5g_interface.channels import CallbackInfoClient, ChannelType
        from era_5g_interface.exceptions import BackPressureException

        self.url, self.robot_id = url, robot_id
        self._latencies_ms: list[float] = []
        self._arrivals = arrivals  # when each result came (wall clock)
        self._errors: list[dict] = []
        self._lock = threading.Lock()
        self._jpeg = ChannelType.JPEG
        self._back_pressure = BackPressureException
        self.client = NetAppClientBase(
            {
                "results": CallbackInfoClient(ChannelType.JSON, self._on_result),
                "data_error": CallbackInfoClient(ChannelType.JSON, self._on_error),
            }
        )

    def _on_result(self, result: dict) -> None:
        with self._lock:
            self._latencies_ms.append((time.perf_counter_ns() - int(result["timestamp"])) / 1e6)
            self._arrivals.append(time.time())

    def _on_error(self, error: dict) -> None:
        with self._lock:
            self._errors.append(error)

    def connect(self) -> None:
        self.client.register(self.url, args={"robot": self.robot_id})

    def stream(self, frames: Iterable[np.ndarray], fps: float, duration_s: float) -> dict:
        """Send `frames` (BGR) at `fps` for `duration_s`, wait `DRAIN_S` for the last results; the summary."""
        period = 1.0 / fps
        sent = due = held_back = 0
        start = time.monotonic()
        for frame in frames:
            if time.monotonic() - start >= duration_s:
                break
            due += 1
            try:
                self.client.send_image(frame, "image", self._jpeg, time.perf_counter_ns())
                sent += 1
            except self._back_pressure:  # its send queue is full: the client drops the frame, the robot goes on
                held_back += 1
            delay = start + due * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # the camera's frame period: pacing, not synchronisation
        elapsed = time.monotonic() - start
        threading.Event().wait(DRAIN_S)  # the last results on their way (the client has no "idle" to wait on)
        with self._lock:
            results = len(self._latencies_ms)
            refused = [e for e in self._errors if e.get("reason") != "superseded"]
            return {
                "frames_sent": sent,
                "results": results,
                "results_per_s": results / elapsed,
                "duration_s": elapsed,
                "lost": 0,  # not told apart here: a frame without a result was superseded by a newer one
                "errors": len(refused),
                "within_deadline": results,
                "within_deadline_per_s": results / elapsed,
                "latencies_ms": list(self._latencies_ms),
                "dropped_client": held_back,
            }

    def close(self) -> None:
        # python-engineio's threaded disconnect can stall on a lost race (upstream): in the background
        threading.Thread(target=self.client.disconnect, daemon=True).start()
