"""The local fallback: the robot's own processor, used while no netapp meets the deadline. Any SDK `Processor` (say
YOLOX-Nano on the robot's CPU through `netapp.models.Detector`), one frame at a time on its own thread, newest frame
wins, so it runs at the rate the robot can afford and never queues stale frames."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

if TYPE_CHECKING:  # importing netapp.sdk would load the server's settings: the robot needs only the contract
    from netapp.sdk.processor import Processor

log = logging.getLogger(__name__)

LOCAL = "local"  # the `source` of its results


class LocalFallback:
    """Runs `processor` on frames handed to `submit`; results and errors come back through the callbacks, from its
    thread, as result messages shaped like a netapp's (timestamps in monotonic ns, `source: local`)."""

    def __init__(
        self,
        processor: Processor,
        on_result: Callable[[dict[str, Any]], None],
        on_error: Callable[[dict[str, Any]], None],
        args: Mapping[str, Any] | None = None,
    ) -> None:
        self.processor = processor
        self.args = dict(args or {})
        self._on_result = on_result
        self._on_error = on_error
        self._cond = threading.Condition()
        self._waiting: tuple[int, np.ndarray | bytes] | None = None
        self._closed = False
        self._thread: threading.Thread | None = None
        self.dropped = 0  # frames replaced by a newer one before the processor was free
        self.expected_ms = 0.0  # what one frame takes here: the warm-up's time, then a moving average

    def start(self, warm_up: tuple[int, int] = (640, 480)) -> None:
        """Load the processor and run it once on a blank `warm_up` frame now (a fallback must be ready before it is
        needed, and the client must know how long it takes), then start its thread."""
        self.processor.load()
        blank = np.zeros((warm_up[1], warm_up[0], 3), np.uint8)
        before = time.monotonic_ns()
        self.processor.process([self.processor.prepare(blank, self.args)])
        self.expected_ms = (time.monotonic_ns() - before) / 1e6
        self._thread = threading.Thread(target=self._run, name="netapp-local", daemon=True)
        self._thread.start()

    def submit(self, timestamp: int, frame: np.ndarray | bytes) -> None:
        with self._cond:
            if self._waiting is not None:
                self.dropped += 1
            self._waiting = (timestamp, frame)
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout=10)

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._waiting is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                timestamp, frame = self._waiting
                self._waiting = None
            self._process(timestamp, frame)

    def _process(self, timestamp: int, frame: np.ndarray | bytes) -> None:
        before = time.monotonic_ns()
        try:
            image = frame if isinstance(frame, np.ndarray) else _decode_jpeg(frame)
            (output,) = self.processor.process([self.processor.prepare(image, self.args)])
        except Exception as exc:  # the robot hears of it; the fallback carries on
            log.warning("the local processor failed: %s", exc)
            self._on_error({"timestamp": timestamp, "error": f"local processing failed: {exc}", "source": LOCAL})
            return
        after = time.monotonic_ns()
        self.expected_ms = 0.8 * self.expected_ms + 0.2 * (after - before) / 1e6
        self._on_result(
            {
                "timestamp": timestamp,
                "timestamp_before_process": before,
                "timestamp_after_process": after,
                **output,
                "source": LOCAL,
            }
        )


def _decode_jpeg(data: bytes) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"could not decode {len(data)} bytes as JPEG")
    return image
