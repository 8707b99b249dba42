"""What a robot knows of its uplink from its results (pure): the rate, the one-way delay, what the rest of the
round trip takes, and how its frames' bytes compare with the accuracy profile's.

* **Delay**: the smallest recent downlink (a result is small and the downlink fast, so it is mostly the one-way
  delay); a frame's uplink is that delay plus its bytes at the uplink's rate (and its encoding).
* **Rate**: each result's bytes over its uplink time less the delay. It falls when two results in a row say so
  (to the higher of the two: one slow result is jitter, two are the link), and rises slowly (a quarter of the way
  to each faster sample): down within two results, up with care.
* **Rest**: the median of the last few results' queue + inference + downlink.
* **Scale**: measured bytes over the profile's for the same setting (another source, another codec), smoothed.
"""

from __future__ import annotations

import statistics
from collections import deque

DELAY_WINDOW = 32  # results over which the smallest downlink is the delay
REST_WINDOW = 5
RISE = 0.25  # of the way to a faster rate sample
SCALE_SMOOTHING = 0.3
MIN_TRANSFER_MS = 1.0  # a frame's transfer time is taken as at least this (timer resolution)


class UplinkEstimate:
    def __init__(self) -> None:
        self.rate_bytes_per_ms: float | None = None
        self.scale = 1.0
        self._downlinks: deque[float] = deque(maxlen=DELAY_WINDOW)
        self._rest: deque[float] = deque(maxlen=REST_WINDOW)
        self._last_rate: float | None = None

    @property
    def base_ms(self) -> float:
        """The uplink's one-way delay (0 before any result)."""
        return min(self._downlinks) if self._downlinks else 0.0

    @property
    def others_ms(self) -> float:
        """What the netapp and the downlink take of a result's latency."""
        return statistics.median(self._rest) if self._rest else 0.0

    @property
    def rate_mbit(self) -> float | None:
        return None if self.rate_bytes_per_ms is None else self.rate_bytes_per_ms * 8e-3

    def add(
        self, bytes_sent: int, uplink_ms: float, downlink_ms: float, others_ms: float, profile_bytes: float
    ) -> None:
        """One result: its frame's bytes and uplink, its downlink and the rest, and the profile's bytes for the
        setting it was sent with."""
        self._downlinks.append(max(0.0, downlink_ms))
        self._rest.append(max(0.0, others_ms))
        if bytes_sent <= 0:
            return
        if profile_bytes > 0:
            ratio = min(10.0, max(0.1, bytes_sent / profile_bytes))
            self.scale += SCALE_SMOOTHING * (ratio - self.scale)
        transfer_ms = max(MIN_TRANSFER_MS, uplink_ms - min(self.base_ms, 0.9 * uplink_ms))
        sample = bytes_sent / transfer_ms
        last, self._last_rate = self._last_rate, sample
        rate = self.rate_bytes_per_ms
        if rate is None:
            self.rate_bytes_per_ms = sample
        elif sample >= rate:
            self.rate_bytes_per_ms = rate + RISE * (sample - rate)
        elif last is not None and last < rate:  # the second slow result in a row: the link is slower
            self.rate_bytes_per_ms = max(sample, last)
