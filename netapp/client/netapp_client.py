"""NetAppClient: send frames to a netapp over HTTP or Socket.IO (5G-ERA), get results by callback or iterator.

`send()` never waits for the network: with a free in-flight slot it encodes and hands the frame to the transport
at once; otherwise the newest frame waits in a one-frame slot (an older waiting frame is dropped and counted) until
fewer than `max_in_flight` frames await their results, and a sender thread encodes and transmits it then. So a
frame is dropped before it is encoded, never after (which matters for H.264, where a lost P-frame would corrupt
the remote decoder).

The client owns that scheduling, the counters and the delivery of results; a frame encoder
(`netapp.client.encoders`) makes the bytes and a transport (`netapp.client.transports`) carries them:
"http" = HTTP + JPEG, "ws" = Socket.IO + JPEG, "h264" = Socket.IO + H.264.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import requests

from netapp.client.encoders import Frame, FrameEncoder, H264StreamEncoder, JpegEncoder
from netapp.client.errors import NetAppError
from netapp.client.stats import ClientStats
from netapp.client.timing import ClockOffsetEstimator, LatencyBreakdown
from netapp.client.transports import SessionSettings, Transport, TransportCallbacks
from netapp.client.transports.http import HttpTransport
from netapp.client.transports.socketio import SocketIOTransport
from netapp.client.urls import http_url
from netapp.protocol import STATE_CHECKPOINT_ARG, STATE_KEY, TRANSPORTS

__all__ = ["NetAppClient", "NetAppError", "Result"]

log = logging.getLogger(__name__)

# What carries each transport's frames (its encoder is chosen in `NetAppClient._new_encoder`).
CARRIERS: dict[str, Callable[[str, SessionSettings, TransportCallbacks], Transport]] = {
    "http": HttpTransport,
    "ws": SocketIOTransport,
    "h264": SocketIOTransport,
}


@dataclass
class Result:
    timestamp: int
    detections: list[dict[str, Any]]
    latency_ms: float  # client send -> client receive
    message: dict[str, Any] = field(repr=False)  # the whole result message (server timestamps, extra fields)
    breakdown: LatencyBreakdown | None = None  # uplink / queue / inference / downlink (None: no server stamps)


class NetAppClient:
    """A robot's connection to one netapp. Thread-safe `send()`; use as a context manager."""

    def __init__(
        self,
        url: str,
        transport: str = "ws",
        *,
        args: dict[str, Any] | None = None,
        robot_id: str | None = None,
        max_in_flight: int = 2,
        on_result: Callable[[Result], None] | None = None,
        on_error: Callable[[dict[str, Any]], None] | None = None,
        jpeg_quality: int = 85,
        connect_timeout_s: float = 10.0,
        result_timeout_s: float = 10.0,
        h264_options: dict[str, str] | None = None,
        checkpoint_every: int = 0,
        token: str | None = None,
    ) -> None:
        if transport not in TRANSPORTS:
            raise ValueError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
        if max_in_flight < 1:
            raise ValueError("max_in_flight must be at least 1")
        self.url = http_url(url)
        self.transport = transport
        self.args = dict(args or {})
        if checkpoint_every:  # a stateful netapp then puts its session state in every Nth result
            self.args[STATE_CHECKPOINT_ARG] = checkpoint_every
        self.robot_id = robot_id
        self.max_in_flight = max_in_flight
        self.on_result = on_result
        self.on_error = on_error
        self.jpeg_quality = jpeg_quality
        self.connect_timeout_s = connect_timeout_s
        self.result_timeout_s = result_timeout_s
        self.h264_options = h264_options
        self.token = token  # the netapp's bearer token, when it needs one
        self.stats = ClientStats()
        self.clock = ClockOffsetEstimator()  # the netapp's clock relative to ours, for the latency breakdown
        self._reported: dict[str, float] | None = None  # our last uplink/downlink, told to the netapp's page
        self._encoder = self._new_encoder()
        self._callbacks = TransportCallbacks(
            on_ready=self._on_ready,
            on_lost=self._lose_in_flight,
            on_result=self._on_result_message,
            on_error=self._on_error_message,
            on_dropped=self._on_dropped,
            on_refused=self._on_refused,
            state_to_restore=lambda: self.state,
            on_restored=self._on_restored,
        )
        self._state: Any = None  # the latest session-state checkpoint (stateful netapps)
        self._state_timestamp = -1
        self._carrier: Transport | None = None
        self._wire = threading.Lock()  # frames are encoded and put on the wire one at a time, in order
        self._cond = threading.Condition()
        self._pending: tuple[int, Frame] | None = None
        self._in_flight: dict[int, int] = {}  # timestamp -> send time (ns)
        self._last_timestamp = 0
        self._closed = False
        self._connected = threading.Event()
        self._results: queue.Queue[Result] = queue.Queue(maxsize=1000)
        self._sender: threading.Thread | None = None

    def _new_encoder(self) -> FrameEncoder:
        if self.transport == "h264":
            return H264StreamEncoder(self.h264_options)
        return JpegEncoder(self.jpeg_quality)

    # -- lifecycle -----------------------------------------------------------------------------------------------

    def connect(self) -> NetAppClient:
        """Register with the netapp (HTTP) or connect and INIT (Socket.IO); raises NetAppError on failure."""
        self._open()
        if self._sender is None:
            self._sender = threading.Thread(target=self._send_loop, name="netapp-sender", daemon=True)
            self._sender.start()
        return self

    def close(self) -> None:
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        if self._sender is not None:
            self._sender.join(timeout=5)
        self._disconnect()
        with self._wire:
            self._encoder.close()

    def __enter__(self) -> NetAppClient:
        return self.connect()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def switch_url(self, url: str) -> None:
        """Move to another netapp (an edge switchover): frames in flight are counted lost, the newest waits."""
        url = http_url(url)
        if url == self.url:
            return
        log.info("switching netapp %s -> %s", self.url, url)
        self._disconnect()
        self.url = url
        self._encoder.restart()  # a new remote decoder needs a keyframe first
        self._open()

    def processor_info(self, timeout_s: float = 2.0) -> dict[str, Any] | None:
        """What the netapp serves (its `/v2` metadata's model: name, platform, ...), None if it does not say."""
        try:
            response = requests.get(f"{self.url}/v2", timeout=timeout_s)
            models = response.json().get("models") if response.ok else None
        except (requests.RequestException, ValueError, AttributeError):
            return None
        return models[0] if isinstance(models, list) and models and isinstance(models[0], dict) else None

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def state(self) -> Any:
        """The latest session state a stateful netapp sent (`checkpoint_every`), or None. A new session (after
        `switch_url()`, a reconnect or a failover) gets it back with SET_STATE before its first frame, so a tracker
        there continues with the same track ids."""
        with self._cond:
            return self._state

    @property
    def session_id(self) -> str | None:
        """The netapp's id of this robot's session (None before connecting)."""
        carrier = self._carrier
        return carrier.session_id if carrier is not None else None

    def _open(self) -> None:
        settings = SessionSettings(
            robot_id=self.robot_id,
            args=dict(self.args),
            max_in_flight=self.max_in_flight,
            connect_timeout_s=self.connect_timeout_s,
            result_timeout_s=self.result_timeout_s,
            token=self.token,
        )
        self._carrier = CARRIERS[self.transport](self.url, settings, self._callbacks)
        self._carrier.connect()

    def _disconnect(self) -> None:
        carrier, self._carrier = self._carrier, None
        self._connected.clear()
        if carrier is not None:
            carrier.close()
        self._lose_in_flight()

    # -- sending ---------------------------------------------------------------------------------------------

    def send(self, frame: Frame, timestamp: int | None = None) -> int:
        """Queue a frame (BGR array, or JPEG bytes for http/ws); returns its timestamp, the key of its result."""
        self._encoder.check(frame)
        with self._cond:
            if self._closed:
                raise NetAppError("the client is closed")
            if timestamp is None:
                timestamp = max(time.time_ns(), self._last_timestamp + 1)
            self._last_timestamp = max(self._last_timestamp, timestamp)
            self.stats.add(offered=1)
            if self.stats.frame_size is None and isinstance(frame, np.ndarray):
                self.stats.frame_size = (frame.shape[1], frame.shape[0])
            send_now = self._pending is None and len(self._in_flight) < self.max_in_flight and self.connected
            if send_now:  # a free slot: transmit from this thread, sparing a thread hop on the latency path
                self._in_flight[timestamp] = time.monotonic_ns()
            else:
                if self._pending is not None:
                    self.stats.add(dropped_client=1)
                self._pending = (timestamp, frame)
                self._cond.notify_all()
        if send_now:
            self._transmit_or_count(timestamp, frame)
        return timestamp

    def _send_loop(self) -> None:
        while True:
            with self._cond:
                while not self._closed and not (
                    self._pending is not None and len(self._in_flight) < self.max_in_flight and self.connected
                ):
                    self._cond.wait(timeout=0.5)
                    self._expire_in_flight()
                if self._closed:
                    return
                timestamp, frame = self._pending
                self._pending = None
                self._in_flight[timestamp] = time.monotonic_ns()
            self._transmit_or_count(timestamp, frame)

    def _transmit_or_count(self, timestamp: int, frame: Frame) -> None:
        try:
            with self._wire:
                encoded = self._encoder.encode(timestamp, frame)
                if encoded is None:  # the encoder is still buffering: no bytes for this frame yet
                    self._settle(timestamp)
                    return
                if self._reported is not None:  # our previous result's uplink and downlink, for the netapp's page
                    encoded.message["metadata"] = {"latency": self._reported}
                self.stats.add(sent=1, bytes_sent=len(encoded.data))
                carrier = self._carrier
                if carrier is None:
                    raise NetAppError("not connected to a netapp")
                carrier.transmit(encoded)
        except Exception as exc:  # a failed send is counted, never raised into the robot's loop or the sender thread
            log.warning("send failed: %s", exc)
            self._settle(timestamp)
            self.stats.add(errors=1)
            self.stats.last_error = str(exc)

    def _expire_in_flight(self) -> None:
        """Called with the lock held: results that never came are counted lost, freeing their slot."""
        deadline = time.monotonic_ns() - int(self.result_timeout_s * 1e9)
        for ts in [ts for ts, sent in self._in_flight.items() if sent < deadline]:
            del self._in_flight[ts]
            self.stats.add(lost=1)

    def _settle(self, timestamp: int | None) -> int | None:
        """Remove a frame from the in-flight set; returns its send time, None if it was not in flight."""
        with self._cond:
            sent = self._in_flight.pop(timestamp, None)
            self._cond.notify_all()
            return sent

    def _settle_superseded(self, timestamp: Any) -> None:
        """Over Socket.IO the netapp answers a frame superseded in its queue with nothing (5G-ERA's way), and it
        processes a robot's frames in order: frames sent before one whose result came are superseded. Settled now,
        not after `result_timeout_s`, so their slots carry new frames and they are counted as dropped, not lost."""
        with self._cond:
            sent_order = list(self._in_flight)  # in the order they were sent
            older = sent_order[: sent_order.index(timestamp)] if timestamp in self._in_flight else []
            for ts in older:
                del self._in_flight[ts]
            if older:
                self._cond.notify_all()
        self.stats.add(dropped_server=len(older))

    # -- what the transport reports --------------------------------------------------------------------------

    def _on_ready(self) -> None:
        self._encoder.restart()  # a new session decodes from a keyframe
        self.clock = ClockOffsetEstimator()  # a reconnect or a switchover may reach another clock
        self._connected.set()
        with self._cond:
            self._cond.notify_all()

    def _lose_in_flight(self) -> None:
        """The connection dropped or was closed: frames in flight will get no result."""
        self._connected.clear()
        with self._cond:
            lost = len(self._in_flight)
            self._in_flight.clear()
            self._cond.notify_all()
        if lost:
            self.stats.add(lost=lost)

    def _on_result_message(self, message: dict[str, Any]) -> None:
        now = time.monotonic_ns()
        if self.transport != "http":
            self._settle_superseded(message.get("timestamp"))
        sent = self._settle(message.get("timestamp"))
        if sent is None:
            return  # a result for a frame already counted lost, or sent before a reconnect
        state = message.get(STATE_KEY)
        if state is not None:
            self._keep_state(message.get("timestamp"), state)
        result = Result(
            message.get("timestamp"),
            message.get("detections", []),
            (now - sent) / 1e6,
            message,
            self.clock.breakdown(sent, now, message),
        )
        self.stats.add_result(result.latency_ms, result.detections, result.breakdown)
        if result.breakdown is not None:
            parts = result.breakdown
            self._reported = {"uplink_ms": round(parts.uplink_ms, 2), "downlink_ms": round(parts.downlink_ms, 2)}
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

    def _on_error_message(self, message: dict[str, Any]) -> None:
        self._encoder.note_error(message)  # before settling: the frame that takes the freed slot may react
        if message.get("timestamp") is not None:
            self._settle(message["timestamp"])
        self.stats.add(errors=1)
        self.stats.last_error = str(message.get("error"))
        if self.on_error is not None:
            try:
                self.on_error(message)
            except Exception:
                log.exception("on_error callback failed")

    def _on_dropped(self, timestamp: int) -> None:
        self._settle(timestamp)
        self.stats.add(dropped_server=1)

    def _on_refused(self, reason: str) -> None:
        self.stats.last_error = reason

    def _keep_state(self, timestamp: int, state: Any) -> None:
        with self._cond:
            if timestamp > self._state_timestamp:  # results may arrive out of order: keep the newest frame's
                self._state, self._state_timestamp = state, timestamp
        self.stats.add(checkpoints=1)

    def _on_restored(self, ok: bool, message: str) -> None:
        if ok:
            self.stats.add(restores=1)
        else:
            self.stats.add(errors=1)
            self.stats.last_error = f"the session state was not restored: {message}"

    # -- results ---------------------------------------------------------------------------------------------

    def results(self, timeout: float | None = None) -> Iterator[Result]:
        """Results as they arrive; stops after `timeout` seconds without one (None: until closed)."""
        while True:
            try:
                yield self._results.get(timeout=timeout if timeout is not None else 0.5)
            except queue.Empty:
                if timeout is not None or self._closed:
                    return

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Wait until nothing is pending or in flight (e.g. before reading the last results)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._pending is not None or self._in_flight:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._cond.wait(timeout=min(remaining, 0.2))
                self._expire_in_flight()
        return True
