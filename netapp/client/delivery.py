"""Result delivery: the first answer to a frame wins (later ones are discarded and counted), and reaches the robot
by its callback or a bounded queue; errors reach `on_error`; a stateful netapp's latest checkpoint is kept for the
next session. Callbacks never raise into the robot's loop or the client's threads."""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from netapp.client.stats import ClientStats
from netapp.client.timing import LatencyBreakdown
from netapp.detections import Detections
from netapp.results import CLASSIFICATIONS_FIELD

log = logging.getLogger(__name__)

QUEUE_SIZE = 1000  # results kept for a robot that reads them with `results()`; the oldest goes first


@dataclass
class Result:
    timestamp: int
    detections: list[dict[str, Any]]
    latency_ms: float  # client send -> client receive
    message: dict[str, Any] = field(repr=False)  # the whole result message (server timestamps, extra fields)
    source: str = ""  # the URL of the netapp that answered, or "local"
    late: bool = False  # arrived after the deadline
    breakdown: LatencyBreakdown | None = None  # uplink / queue / inference / downlink (None: no netapp stamps)
    source_stamp_ns: int | None = None  # the frame's header stamp (a recording) or capture time (`netapp stream`)
    frame_index: int | None = None  # the frame's place in the stream, from 0 (`netapp stream`)
    sent: dict[str, Any] | None = None  # what its frame went on the wire with, when the uplink adapts (`adapt`)

    @property
    def classifications(self) -> list[dict[str, Any]]:
        """An image classifier's top k, `{"class", "class_name", "score"}` each, best first ([] when none)."""
        value = self.message.get(CLASSIFICATIONS_FIELD)
        return [c for c in value if isinstance(c, dict)] if isinstance(value, list) else []

    def typed(self) -> Detections:
        """Its detections as columns (`netapp.detections`), read leniently: a malformed detection is set aside, the
        rest are kept. Read anew on each call (the result's list is the robot's to change)."""
        return Detections.from_wire(self.detections, strict=False)

    def masks(self, height: int, width: int) -> list[np.ndarray | None]:
        """Each detection's mask as a boolean `height` x `width` array of the robot's frame (None where a detection
        has none, or it or its mask is malformed), in the order of `detections`."""
        typed = self.typed()
        out: list[np.ndarray | None] = [None] * len(self.detections)
        for k, place in enumerate(typed.wire_places()):
            out[place] = typed.mask_array(k, height, width)
        return out

    def keypoints(self) -> list[np.ndarray | None]:
        """Each detection's keypoints as a K x 3 float array (x, y in the robot's frame, score), None where a
        detection has none or it or they are malformed, in the order of `detections`."""
        typed = self.typed()
        out: list[np.ndarray | None] = [None] * len(self.detections)
        if typed.keypoints is not None:
            present = typed.has_keypoints()
            for k, place in enumerate(typed.wire_places()):
                out[place] = typed.keypoints[k].astype(np.float64) if present[k] else None
        return out


class ResultDelivery:
    """The first answer to each frame, to `on_result` or the queue `results()` reads; errors to `on_error`."""

    def __init__(
        self,
        stats: ClientStats,
        on_result: Callable[[Result], None] | None,
        on_error: Callable[[dict[str, Any]], None] | None,
    ) -> None:
        self.on_result = on_result
        self.on_error = on_error
        self._stats = stats
        self._results: queue.Queue[Result] = queue.Queue(maxsize=QUEUE_SIZE)

    def deliver(self, first: bool, result: Result) -> None:
        """A result for a frame: `first` when no one answered that frame before."""
        if not first:  # another netapp (or the fallback) answered this frame already
            self._stats.add(discarded=1)
            return
        self._stats.add_result(result.latency_ms, result.detections, result.source, result.late, result.breakdown)
        if self.on_result is not None:
            try:
                self.on_result(result)
            except Exception:
                log.exception("on_result callback failed")
            return
        try:
            self._results.put_nowait(result)
        except queue.Full:  # a robot that never reads must not grow memory: keep the newest
            self._results.get_nowait()
            self._results.put_nowait(result)

    def error(self, message: dict[str, Any]) -> None:
        if self.on_error is not None:
            try:
                self.on_error(message)
            except Exception:
                log.exception("on_error callback failed")

    def results(self, timeout: float | None, closed: threading.Event) -> Iterator[Result]:
        """Results as they arrive; stops after `timeout` seconds without one (None: once `closed`)."""
        while True:
            try:
                yield self._results.get(timeout=timeout if timeout is not None else 0.5)
            except queue.Empty:
                if timeout is not None or closed.is_set():
                    return


class Checkpoints:
    """The latest session state a stateful netapp sent (`checkpoint_every`): a new session gets it back."""

    def __init__(self, stats: ClientStats) -> None:
        self._stats = stats
        self._lock = threading.Lock()
        self._state: Any = None
        self._timestamp = -1

    @property
    def latest(self) -> Any:
        with self._lock:
            return self._state

    def keep(self, timestamp: int, state: Any) -> None:
        with self._lock:
            if timestamp > self._timestamp:  # results may arrive out of order: keep the newest frame's
                self._state, self._timestamp = state, timestamp
        self._stats.add(checkpoints=1)

    def restored(self, ok: bool, message: str) -> None:
        """How restoring it in a new session went."""
        if ok:
            self._stats.add(restores=1)
        else:
            self._stats.add(errors=1)
            self._stats.last_error = f"the session state was not restored: {message}"
