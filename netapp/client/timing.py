"""Where a result's latency went: the robot's clock offset to the netapp, estimated as NTP does (pure).

Four timestamps per frame, two clocks, no extra messages: the robot stamps t1 when it hands the frame to the
transport (its monotonic clock, before encoding) and t4 when the result arrives; the netapp stamps t2 on receipt
(`recv_timestamp`), when processing starts and ends (`timestamp_before_process`, `timestamp_after_process`) and t3
when it sends the result (`send_timestamp`), on its own monotonic clock. Per sample (RFC 5905):

    offset = ((t2 - t1) + (t3 - t4)) / 2      # netapp clock minus robot clock
    delay  = (t4 - t1) - (t3 - t2)            # the round trip spent on the network (and in encoding)

A single sample assumes the two directions take equally long. As NTP's clock filter does, the estimator keeps the
last samples and trusts the one with the smallest delay (the least queued, so the most symmetric one); with the
offset from that sample, each result's uplink and downlink are measured separately, even when they differ.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any

from netapp.protocol import RESULT_STAMPS

PARTS = ("uplink_ms", "queue_ms", "inference_ms", "downlink_ms")


@dataclass(frozen=True)
class LatencyBreakdown:
    """One result's latency split in four; they add up to `total_ms` (robot send -> robot receive).

    uplink: robot encode + network to the netapp; queue: waiting for the inference thread; inference: decode,
    preprocessing, the model and postprocessing (the batch's); downlink: serialising the result + network back.
    """

    uplink_ms: float
    queue_ms: float
    inference_ms: float
    downlink_ms: float
    total_ms: float

    def as_dict(self) -> dict[str, float]:
        return {k: round(v, 2) for k, v in asdict(self).items()}


def ntp_sample(t1: int, t2: int, t3: int, t4: int) -> tuple[int, int]:
    """(offset, delay) in ns of one exchange: t1/t4 on the robot's clock, t2/t3 on the netapp's."""
    return ((t2 - t1) + (t3 - t4)) // 2, (t4 - t1) - (t3 - t2)


def server_stamps(message: dict[str, Any]) -> tuple[int, int, int, int] | None:
    """The netapp's four timestamps of a result message, or None when any is missing or not an integer."""
    stamps = [message.get(k) for k in RESULT_STAMPS]
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in stamps):
        return None
    recv, before, after, send = stamps
    if not recv <= send or not before <= after:
        return None  # not one clock's stamps: nothing to learn from them
    return recv, before, after, send


def breakdown(t1: int, t4: int, stamps: tuple[int, int, int, int], offset_ns: int) -> LatencyBreakdown:
    """Split t4 - t1 with the netapp's stamps and the estimated offset (netapp minus robot clock).

    Uplink and downlink are floored at 0 (an offset estimate off by a little must not show negative time); the
    four parts then still add up to the total, the downlink taking the remainder.
    """
    recv, before, after, _send = stamps
    total = t4 - t1
    queue = max(0, before - recv)
    inference = max(0, after - before)
    uplink = min(max(0, recv - offset_ns - t1), max(0, total - queue - inference))
    downlink = max(0, total - uplink - queue - inference)
    ms = 1e-6
    return LatencyBreakdown(uplink * ms, queue * ms, inference * ms, downlink * ms, total * ms)


def span_offset(offset_ns: int, t1: int, t2: int, t3: int, t4: int) -> int:
    """The offset to place one exchange's robot stamps on the netapp's clock (traces): the estimate, kept within
    [t3 - t4, t2 - t1], so that the frame leaves the robot no later than the netapp receives it and its result
    arrives no earlier than it was sent (an estimate off by a little must not reorder the two sides' spans)."""
    return min(max(offset_ns, t3 - t4), t2 - t1)


class ClockOffsetEstimator:
    """The netapp-minus-robot clock offset from the minimum-delay sample among the last `window` exchanges."""

    def __init__(self, window: int = 32) -> None:
        self._samples: deque[tuple[int, int]] = deque(maxlen=window)  # (delay, offset)
        self._lock = threading.Lock()  # results arrive on several threads (HTTP)

    def add(self, t1: int, t2: int, t3: int, t4: int) -> int:
        """Record one exchange; returns the current offset estimate in ns."""
        offset, delay = ntp_sample(t1, t2, t3, t4)
        with self._lock:
            if delay >= 0:  # a negative delay means the stamps are inconsistent: ignore the sample
                self._samples.append((delay, offset))
            return min(self._samples)[1] if self._samples else offset

    @property
    def offset_ns(self) -> int | None:
        with self._lock:
            return min(self._samples)[1] if self._samples else None

    def breakdown(self, t1: int, t4: int, message: dict[str, Any]) -> LatencyBreakdown | None:
        """Add this result as a sample and split its latency; None when the message lacks the netapp's stamps."""
        stamps = server_stamps(message)
        if stamps is None:
            return None
        offset = self.add(t1, stamps[0], stamps[3], t4)
        return breakdown(t1, t4, stamps, offset)
