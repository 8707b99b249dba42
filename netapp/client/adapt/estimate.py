"""What a robot knows of its uplink from its results (pure): the rate, the round trip's fixed delay, what the netapp
takes, and how its frames' bytes compare with the accuracy profile's.

Each result gives the frame's bytes, its latency (the robot's send to receipt, on the robot's clock alone) and the
netapp's own queue and inference time (on the netapp's clock alone). What is left, the **network time**, is the
round trip's fixed delay plus the frame's bytes at the uplink's rate (and its encoding, which grows with it too):
`network = 2 * delay + bytes / rate`. (The breakdown's uplink/downlink split is not used: it assumes a symmetric
path, and a robot's uplink carries big frames one way and small results back, which shifts it by half a frame's
transfer time.)

* **Delay**: the line through the fastest results of small and of large frames (the lower envelope of network
  time against bytes, once frames of different sizes have been sent), else 0: a rate that includes the delay is
  lower than the link's, so the controller errs on the safe side until it knows.
* **Rate**: each result's bytes over its transfer time: its network time less the delay, but no more than the time
  since the previous result's network part ended (`end_ms`: its arrival less the netapp's time; plus `JITTER_MS`):
  a frame that queued behind another on the uplink was on the wire only since that one left it, so its wait is not
  taken for a slow link (the delivery rate: without it, the first frames after a drop, queued behind the big ones,
  said the link was ten times slower than it was, and the frame rate took tens of seconds to come back). It
  falls when two results in a row say so (to the higher of the two: one slow result is jitter, two are the link),
  and rises slowly (a quarter of the way to each faster sample): down within two results, up with care; within one
  where the result was too late to be jitter (the controller says: `SURE_LATE` times the budget, a link that fell
  tenfold at once).
* **Netapp**: the median of the last few results' queue + inference.
* **Scale**: measured bytes over the profile's for the same setting (another source, another codec), smoothed.
"""

from __future__ import annotations

import statistics
from collections import deque

from netapp.client.stats import percentile

SAMPLES = 64  # (bytes, network) pairs the delay is fitted on
NETAPP_WINDOW = 5
RISE = 0.25  # of the way to a faster rate sample
SCALE_SMOOTHING = 0.3
MIN_TRANSFER_MS = 1.0  # a frame's transfer time is taken as at least this (timer resolution)
SPREAD = 1.2  # the larger frames' median size over the smaller ones', at least, to fit a line
ENVELOPE = 20  # percentile of network time that stands for "the fastest" of a size
LATENCY_WINDOW = 16  # results whose median latency says how many frames the robot needs in flight
JITTER_MS = 10.0  # added to the time between two results' network ends: the link's jitter, both ways


class UplinkEstimate:
    def __init__(self) -> None:
        self.rate_bytes_per_ms: float | None = None
        self.scale = 1.0  # of JPEG frames (the transport's own codec)
        self.scales: dict[str, float] = {}  # of each codec the adapter chose (`scale_of`)
        self.round_trip_ms = 0.0  # the fixed part of the network time: twice the one-way delay
        self._samples: deque[tuple[int, float]] = deque(maxlen=SAMPLES)
        self._netapp: deque[float] = deque(maxlen=NETAPP_WINDOW)
        self._latencies: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._last_rate: float | None = None
        self._last_end_ms: float | None = None  # when the previous result's network part ended (`add`'s end_ms)

    @property
    def netapp_ms(self) -> float:
        """What the netapp takes of a result's latency (queue + inference)."""
        return statistics.median(self._netapp) if self._netapp else 0.0

    @property
    def latency_ms(self) -> float | None:
        """A result's latency, the median of the last few (None: none yet)."""
        return statistics.median(self._latencies) if self._latencies else None

    @property
    def link_free_s(self) -> float | None:
        """When the uplink last was free, as far as the results tell: the last result's frame left it then (the end
        of its network part less the round trip; None: no result yet)."""
        return None if self._last_end_ms is None else (self._last_end_ms - self.round_trip_ms) / 1000.0

    @property
    def rate_mbit(self) -> float | None:
        return None if self.rate_bytes_per_ms is None else self.rate_bytes_per_ms * 8e-3

    def scale_of(self, codec: str | None) -> float:
        """Measured bytes over the profile's for frames of `codec` (None: the transport's own): each codec's own, an
        H.264 stream's bytes say nothing of a JPEG's."""
        return self.scale if codec is None else self.scales.get(codec, 1.0)

    def add(
        self,
        bytes_sent: int,
        latency_ms: float,
        netapp_ms: float,
        profile_bytes: float,
        sure: bool = False,
        codec: str | None = None,
        end_ms: float | None = None,
    ) -> None:
        """One result: its frame's bytes, its latency, the netapp's share of it, and the profile's bytes for the
        setting it was sent with; `sure`: a slower rate is taken at once (a result too late to be jitter); `end_ms`:
        when its network part ended (its arrival less the netapp's time, on any one clock; None: not known)."""
        self._netapp.append(max(0.0, netapp_ms))
        self._latencies.append(latency_ms)
        if bytes_sent <= 0:
            return
        network_ms = max(0.0, latency_ms - netapp_ms)
        self._samples.append((bytes_sent, network_ms))
        self._fit_delay()
        if profile_bytes > 0:
            ratio = min(10.0, max(0.1, bytes_sent / profile_bytes))
            scale = self.scale_of(codec)
            scale += SCALE_SMOOTHING * (ratio - scale)
            if codec is None:
                self.scale = scale
            else:
                self.scales[codec] = scale
        sample = bytes_sent / max(
            MIN_TRANSFER_MS, transfer_ms(network_ms, self.round_trip_ms, end_ms, self._last_end_ms)
        )
        if end_ms is not None:
            self._last_end_ms = end_ms if self._last_end_ms is None else max(self._last_end_ms, end_ms)
        last, self._last_rate = self._last_rate, sample
        rate = self.rate_bytes_per_ms
        if rate is None:
            self.rate_bytes_per_ms = sample
        elif sample >= rate:
            self.rate_bytes_per_ms = rate + RISE * (sample - rate)
        elif sure:
            self.rate_bytes_per_ms = sample
        elif last is not None and last < rate:  # the second slow result in a row: the link is slower
            self.rate_bytes_per_ms = max(sample, last)

    def _fit_delay(self) -> None:
        ordered = sorted(self._samples)
        half = len(ordered) // 2
        small, large = ordered[:half], ordered[half:]
        if len(small) < 4 or statistics.median(b for b, _ in large) < SPREAD * statistics.median(b for b, _ in small):
            return
        b1, n1 = statistics.median(b for b, _ in small), percentile([n for _, n in small], ENVELOPE)
        b2, n2 = statistics.median(b for b, _ in large), percentile([n for _, n in large], ENVELOPE)
        slope = (n2 - n1) / (b2 - b1)  # ms per byte: 1 / rate
        if slope <= 0:
            return  # the network time does not grow with the bytes here: nothing to learn
        self.round_trip_ms = min(max(0.0, n1 - slope * b1), min(n for _, n in self._samples))


def transfer_ms(network_ms: float, round_trip_ms: float, end_ms: float | None, last_end_ms: float | None) -> float:
    """How long a frame was on the uplink, at most: its network time less the fixed round trip, and no more than the
    time since the previous result's network part ended (it could not go before that one had left), plus
    `JITTER_MS` (see the module)."""
    transfer = network_ms - round_trip_ms
    if end_ms is not None and last_end_ms is not None and end_ms > last_end_ms:
        transfer = min(transfer, end_ms - last_end_ms + JITTER_MS)
    return transfer
