"""Sending: `send()` never waits for the network. With a free slot where the policy routes the frame, the robot's
own thread encodes and transmits it at once; otherwise the newest frame waits in the ledger (an older waiting
frame is dropped and counted) and the sender thread sends it once a slot frees, or a paced netapp's hold ends. So a
frame is dropped before it is encoded, never after (a lost H.264 P-frame would corrupt the remote decoder). The
sender thread also expires frames past their deadline or the result timeout."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence

import cv2
import numpy as np

from netapp.client.encoders import Frame
from netapp.client.errors import ConnectionLost
from netapp.client.fallback import LocalFallback
from netapp.client.ledger import FALLBACK_TARGET, Claim, Ledger
from netapp.client.link import NetAppLink
from netapp.client.send_settings import SendSettings
from netapp.client.sizing import Size, send_size
from netapp.client.stats import ClientStats
from netapp.client.switching import Switcher
from netapp.client.tracing import FrameTraces
from netapp.client.wire import WireSequencer
from netapp.frame import EncodedFrame

log = logging.getLogger(__name__)

IDLE_TICK_S = 0.5  # the sender looks at the frames in flight at least this often (a quarter deadline with one)
# Shrinking a frame to less than this scale averages areas (bilinear would skip source pixels: aliasing); from it
# up, bilinear, which is what the model's own letterbox does (`netapp/models/preprocess.py`), so the model sees the
# pixels it would have made from the full frame, at a seventh of area averaging's time (640x480 to 416x312: 0.25
# against 1.8 ms, on the path of every live frame).
AREA_BELOW_SCALE = 0.5


class FrameSender:
    """`send()` and the sender thread: frames claimed in the ledger go on the wire in turn (see the module)."""

    def __init__(
        self,
        links: Sequence[NetAppLink],
        ledger: Ledger,
        wire: WireSequencer,
        switcher: Switcher,
        fallback: LocalFallback | None,
        stats: ClientStats,
        deadline_ms: float | None,
        result_timeout_s: float,
        closed: threading.Event,
        settings: SendSettings,
        full_frames: bool = False,
        on_wire: Callable[[int, int], None] | None = None,
        traces: FrameTraces | None = None,
        in_flight_cap: Callable[[], int | None] | None = None,
    ) -> None:
        self._links = links
        self._ledger = ledger
        self._wire = wire
        self._switcher = switcher
        self._fallback = fallback
        self._stats = stats
        self._deadline_ms = deadline_ms
        self._timeout_ns = int(result_timeout_s * 1e9)
        self._closed = closed
        self._tick_s = IDLE_TICK_S if deadline_ms is None else min(IDLE_TICK_S, deadline_ms / 4000)
        self._thread: threading.Thread | None = None
        # Read once per frame as it goes on the wire; replaced whole (never changed in place) by `NetAppClient`.
        self.settings = settings
        self._full_frames = full_frames  # no fitting to the netapp's processor (the long-side cap still holds)
        self._on_wire = on_wire  # (timestamp, bytes) of each frame put on the wire (the uplink's adapter)
        self._traces = traces  # each frame's trace (docs/tracing.md); None: tracing is off
        # The most frames in flight the uplink needs (the adapter's, `netapp.client.adapt.admission`; None: the
        # pacer's alone): a frame beyond it waits for a result, as it does for the pacer's window.
        self._in_flight_cap = in_flight_cap

    def send(self, frame: Frame, timestamp: int | None) -> int:
        self._links[0].encoder.check(frame)
        timestamp, claim = self._ledger.offer(frame, timestamp, self._route)
        self._stats.add(offered=1)
        if self._stats.frame_size is None and isinstance(frame, np.ndarray):
            self._stats.frame_size = (frame.shape[1], frame.shape[0])
        if claim is not None:  # a free slot: transmit from this thread, sparing a thread hop on the latency path
            self._transmit(claim)
        return timestamp

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="netapp-sender", daemon=True)
            self._thread.start()

    def join(self) -> None:
        if self._thread is not None:
            self._thread.join(timeout=5)

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait until nothing is waiting or in flight, expiring frames meanwhile."""
        deadline = time.monotonic() + timeout_s
        missed = False
        while not (idle := self._ledger.wait_idle(max(0.0, min(deadline - time.monotonic(), 0.2)))):
            missed |= self._expire()
            if time.monotonic() >= deadline:
                break
        if missed:
            self._switcher.update("deadlines missed")
        return idle

    def _run(self) -> None:
        while not self._closed.is_set():
            claim = self._ledger.claim_waiting(self._route, self._sleep_s)
            if claim is not None:
                self._transmit(claim)
            elif not self._closed.is_set() and self._expire():
                self._switcher.update("deadlines missed")

    def _route(self, now: int, in_flight_at: Callable[[int], int]) -> list[int]:
        """Called by the ledger under its lock: the connected netapps the policy routes a frame to whose pacer lets
        one more go now, and the fallback."""
        route = self._switcher.route(now)
        cap = self._in_flight_cap() if self._in_flight_cap is not None else None
        targets = [
            i
            for i in (*route.netapps, *route.probes)
            if self._links[i].accepts(in_flight_at(i), now) and (cap is None or in_flight_at(i) < cap)
        ]
        if route.local:
            targets.append(FALLBACK_TARGET)
        return targets

    def _sleep_s(self, waiting: bool) -> float:
        """How long the sender may sleep: a tick, or less when a frame waits for a paced netapp's hold to end."""
        if not waiting:
            return self._tick_s
        now = time.monotonic_ns()
        held = [w for link in self._links if (w := link.hold_ns(now)) > 0]
        return min(self._tick_s, min(held) / 1e9) if held else self._tick_s

    def _expire(self) -> bool:
        """Frames past their deadline are misses where they wait (one more each further deadline without an
        answer), past the result timeout lost; True on a miss."""
        again_ns = None if self._deadline_ms is None else self._deadline_ms * 1e6  # each deadline it stays silent
        missed = self._ledger.expire(self._miss_after_ns(), self._timeout_ns, again_ns)
        for i in missed:
            self._switcher.learn(i, on_time=False)
        return bool(missed)

    def _miss_after_ns(self) -> float | None:
        """When a frame still waiting at a netapp counts as a miss there: at its deadline, or with a fallback, once
        there is just time left for the robot to process it (so the fallback can still answer in time)."""
        if self._deadline_ms is None:
            return None
        local_ms = self._fallback.expected_ms if self._fallback is not None else 0.0
        return max(self._deadline_ms / 2, self._deadline_ms - local_ms) * 1e6

    def _transmit(self, claim: Claim) -> None:
        if FALLBACK_TARGET in claim.targets:
            assert self._fallback is not None
            self._fallback.submit(claim.timestamp, claim.frame)
        traces = self._traces
        trace = traces.begin(claim.timestamp, claim.sent_ns) if traces is not None else None
        with self._wire.turn(claim.ticket):
            self._put_on_wire(claim, trace)
        if traces is not None:
            traces.on_wire(claim.timestamp, time.monotonic_ns())

    def _put_on_wire(self, claim: Claim, trace: dict[str, str] | None) -> None:
        timestamp, frame, settings = claim.timestamp, claim.frame, self.settings
        source: Size | None = (frame.shape[1], frame.shape[0]) if isinstance(frame, np.ndarray) else None
        resized: dict[Size, np.ndarray] = {}  # by size: netapps with one model share one resize
        encoded: dict[tuple[int, Size | None], EncodedFrame | None] = {}  # by encoder and size: one JPEG for all
        for i in claim.targets:
            if i == FALLBACK_TARGET:
                continue
            link = self._links[i]
            try:
                fit = link.input_size
                sent = None if source is None else send_size(source, fit, settings.long_side, self._full_frames)
                key = (id(link.encoder), sent)
                if key not in encoded:
                    picture = frame if sent is None or sent == source else _resized(resized, frame, sent)
                    encoded[key] = link.encoder.encode(timestamp, picture, settings)
                message = encoded[key]
                if message is None:  # the encoder is still buffering: no bytes for this frame yet
                    self._ledger.settle(i, timestamp)
                    continue
                self._stats.add(sent=1, bytes_sent=message.size)
                self._stats.sent_size = sent
                if self._on_wire is not None:
                    self._on_wire(timestamp, message.size)
                sizes = None if sent is None else (sent, source)
                link.transmit(message, self._deadline_ms, sizes, trace)  # type: ignore[arg-type]
            except ConnectionLost:  # lost like the frames in flight there, not an error
                self._ledger.lose(i, timestamp)
            except Exception as exc:  # counted, never raised into the robot's loop or the sender thread
                log.warning("send to %s failed: %s", link.url, exc)
                self._ledger.settle(i, timestamp)
                self._stats.add(errors=1)
                self._stats.last_error = str(exc)
                self._switcher.outcome(i, on_time=False, reason=f"{link.url}: send failed")


def _resized(cache: dict[Size, np.ndarray], frame: np.ndarray, size: Size) -> np.ndarray:
    """`frame` at `size` (`shrink`), made once per frame and size."""
    if size not in cache:
        cache[size] = shrink(frame, size)
    return cache[size]


def shrink(frame: np.ndarray, size: Size) -> np.ndarray:
    """`frame` scaled down to `size` as it goes on the wire (see AREA_BELOW_SCALE)."""
    height, width = frame.shape[:2]
    scale = min(size[0] / width, size[1] / height)
    return cv2.resize(frame, size, interpolation=cv2.INTER_AREA if scale < AREA_BELOW_SCALE else cv2.INTER_LINEAR)
