"""NetAppClient: send frames to a netapp over HTTP or Socket.IO (5G-ERA), get results by callback or iterator.

`send()` never waits for the network: with a free in-flight slot it encodes and hands the frame to the transport
at once; otherwise the newest frame waits in a one-frame slot (an older waiting frame is dropped and counted) until
fewer than `max_in_flight` frames await their results, and a sender thread encodes and transmits it then. So a
frame is dropped before it is encoded, never after (which matters for H.264, where a lost P-frame would corrupt
the remote decoder).
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import requests
import socketio

from netapp.client.stats import ClientStats
from netapp.client.timing import ClockOffsetEstimator, LatencyBreakdown
from netapp.client.urls import http_url
from netapp.protocol import (
    COMMAND_EVENT,
    CONTROL_NAMESPACE,
    DATA_ERROR_EVENT,
    DATA_NAMESPACE,
    H264_EVENT,
    H264_KEYFRAME_REASONS,
    IMAGE_EVENT,
    RESULTS_EVENT,
    TRANSPORTS,
    CommandType,
)

log = logging.getLogger(__name__)


class NetAppError(Exception):
    """The netapp could not be reached or refused the session."""


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
    ) -> None:
        if transport not in TRANSPORTS:
            raise ValueError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
        if max_in_flight < 1:
            raise ValueError("max_in_flight must be at least 1")
        if transport == "h264":
            from netapp.client.h264 import require_av

            require_av()  # PyAV is an optional extra: say so now rather than on every frame
        self.url = http_url(url)
        self.transport = transport
        self.args = dict(args or {})
        self.robot_id = robot_id
        self.max_in_flight = max_in_flight
        self.on_result = on_result
        self.on_error = on_error
        self.jpeg_quality = jpeg_quality
        self.connect_timeout_s = connect_timeout_s
        self.result_timeout_s = result_timeout_s
        self.h264_options = h264_options
        self.stats = ClientStats()
        self.clock = ClockOffsetEstimator()  # the netapp's clock relative to ours, for the latency breakdown
        self._reported: dict[str, float] | None = None  # our last uplink/downlink, told to the netapp's page
        self._cond = threading.Condition()
        self._pending: tuple[int, Any] | None = None
        self._in_flight: dict[int, int] = {}  # timestamp -> send time (ns)
        self._last_timestamp = 0
        self._closed = False
        self._connected = threading.Event()
        self._results: queue.Queue[Result] = queue.Queue(maxsize=1000)
        self._sio: socketio.Client | None = None
        self._http: ThreadPoolExecutor | None = None
        self._http_local = threading.local()
        self._session_id: str | None = None
        self._encoder = None  # H.264 encoder, created lazily for the frame size
        self._keyframe_wanted = False  # the netapp's decoder lost the stream: restart it with the next frame
        self._stream_start_ts = 0  # timestamp of the last frame that started a new H.264 stream
        self._sender: threading.Thread | None = None

    # -- lifecycle -----------------------------------------------------------------------------------------------

    def connect(self) -> NetAppClient:
        """Register with the netapp (HTTP) or connect and INIT (Socket.IO); raises NetAppError on failure."""
        if self.transport == "http":
            self._http = ThreadPoolExecutor(self.max_in_flight, thread_name_prefix="netapp-http")
            self._register_http()
        else:
            self._connect_socketio()
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
        if self._http is not None:
            self._http.shutdown(wait=True, cancel_futures=True)

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
        self._encoder = None  # a new remote decoder needs a keyframe first
        self.clock = ClockOffsetEstimator()  # another machine's clock
        if self.transport == "http":
            self._register_http()
        else:
            self._connect_socketio()

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

    # -- sending ---------------------------------------------------------------------------------------------

    def send(self, frame: np.ndarray | bytes, timestamp: int | None = None) -> int:
        """Queue a frame (BGR array, or JPEG bytes for http/ws); returns its timestamp, the key of its result."""
        if self.transport == "h264" and not isinstance(frame, np.ndarray):
            raise TypeError("the h264 transport takes BGR numpy frames")
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

    def _transmit_or_count(self, timestamp: int, frame: np.ndarray | bytes) -> None:
        try:
            self._transmit(timestamp, frame)
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

    def _settle(self, timestamp: int) -> int | None:
        """Remove a frame from the in-flight set; returns its send time, None if it was not in flight."""
        with self._cond:
            sent = self._in_flight.pop(timestamp, None)
            self._cond.notify_all()
            return sent

    def _encode_jpeg(self, frame: np.ndarray | bytes) -> bytes:
        if isinstance(frame, (bytes, bytearray)):
            return bytes(frame)
        ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise ValueError("could not encode the frame as JPEG")
        return buf.tobytes()

    def _transmit(self, timestamp: int, frame: np.ndarray | bytes) -> None:
        if self.transport == "http":
            data = self._encode_jpeg(frame)
            self.stats.add(sent=1, bytes_sent=len(data))
            assert self._http is not None
            self._http.submit(self._post_frame, timestamp, data)
            return
        if self.transport == "h264":
            from netapp.client.h264 import encode_frame

            with self._cond:
                encoder, self._keyframe_wanted = (None if self._keyframe_wanted else self._encoder), False
            if encoder is None:
                self._stream_start_ts = timestamp
            message, self._encoder = encode_frame(encoder, frame, timestamp, self.h264_options)
            event = H264_EVENT
            if message is None:  # the encoder is still buffering: no packet for this frame yet
                self._settle(timestamp)
                return
            size = len(message["frame"])
        else:
            data = self._encode_jpeg(frame)
            message, event, size = {"timestamp": timestamp, "frame": data}, IMAGE_EVENT, len(data)
        if self._reported is not None:
            message["metadata"] = {"latency": self._reported}
        self.stats.add(sent=1, bytes_sent=size)
        assert self._sio is not None
        self._sio.emit(event, message, namespace=DATA_NAMESPACE)

    # -- receiving -------------------------------------------------------------------------------------------

    def _on_result_message(self, message: dict[str, Any]) -> None:
        now = time.monotonic_ns()
        sent = self._settle(message.get("timestamp"))
        if sent is None:
            return  # a result for a frame already counted lost, or sent before a reconnect
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

    def _on_error_message(self, message: Any) -> None:
        message = message if isinstance(message, dict) else {"error": str(message)}
        if (
            self.transport == "h264"
            and message.get("reason") in H264_KEYFRAME_REASONS
            and (message.get("timestamp") or 0) >= self._stream_start_ts  # not about a stream already restarted
        ):
            with self._cond:  # before settling: the frame that takes the freed slot starts the new stream
                self._keyframe_wanted = True
        if message.get("timestamp") is not None:
            self._settle(message["timestamp"])
        self.stats.add(errors=1)
        self.stats.last_error = str(message.get("error"))
        if self.on_error is not None:
            try:
                self.on_error(message)
            except Exception:
                log.exception("on_error callback failed")

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

    # -- HTTP ------------------------------------------------------------------------------------------------

    def _http_session(self) -> requests.Session:
        session = getattr(self._http_local, "session", None)
        if session is None:
            session = self._http_local.session = requests.Session()
        return session

    def _register_http(self) -> None:
        try:
            response = requests.post(
                f"{self.url}/register",
                json={"robot_id": self.robot_id, "args": self.args},
                timeout=self.connect_timeout_s,
            )
            response.raise_for_status()
        except requests.RequestException as exc:
            raise NetAppError(f"cannot register with {self.url}: {exc}") from exc
        self._session_id = response.json()["session_id"]
        self._connected.set()
        with self._cond:
            self._cond.notify_all()

    def _post_frame(self, timestamp: int, data: bytes) -> None:
        headers = {"X-Session-Id": self._session_id or "", "X-Timestamp": str(timestamp), "Content-Type": "image/jpeg"}
        if self._reported is not None:
            headers["X-Robot-Latency"] = json.dumps(self._reported)
        try:
            response = self._http_session().post(
                f"{self.url}/send_image",
                params={"wait": "true"},
                data=data,
                headers=headers,
                timeout=self.result_timeout_s,
            )
        except requests.RequestException as exc:
            self._on_error_message({"timestamp": timestamp, "error": f"request failed: {exc}"})
            return
        if response.status_code == 200:
            self._on_result_message(response.json())
        elif response.status_code == 409:
            self._settle(timestamp)
            self.stats.add(dropped_server=1)
        else:
            body = _json_or_text(response)
            self._on_error_message(
                {"timestamp": timestamp, "error": body.get("error", body), "status": response.status_code}
            )
            if response.status_code in (404, 410):  # the netapp restarted or expired us: register again
                try:
                    self._register_http()
                except NetAppError as exc:
                    log.warning("%s", exc)

    # -- Socket.IO ---------------------------------------------------------------------------------------------

    def _connect_socketio(self) -> None:
        sio = socketio.Client(
            reconnection=True,
            reconnection_attempts=0,
            reconnection_delay=0.5,
            reconnection_delay_max=5,
            handle_sigint=False,
        )
        sio.on(RESULTS_EVENT, self._on_ws_result, namespace=DATA_NAMESPACE)
        sio.on(DATA_ERROR_EVENT, self._on_error_message, namespace=DATA_NAMESPACE)
        sio.on("connect", self._on_control_connect, namespace=CONTROL_NAMESPACE)
        sio.on("disconnect", self._on_ws_disconnect, namespace=CONTROL_NAMESPACE)
        self._sio = sio
        try:
            sio.connect(self.url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], wait_timeout=self.connect_timeout_s)
        except socketio.exceptions.ConnectionError as exc:
            raise NetAppError(f"cannot connect to {self.url}: {exc}") from exc
        if not self._connected.wait(self.connect_timeout_s):
            raise NetAppError(f"{self.url} did not acknowledge INIT within {self.connect_timeout_s} s")

    def _on_ws_result(self, message: Any) -> None:
        if isinstance(message, dict):
            self._on_result_message(message)

    def _on_control_connect(self) -> None:
        # INIT waits for its ack, which arrives on the thread that runs this handler: send it from another thread.
        threading.Thread(target=self._init_session, args=(self._sio,), name="netapp-init", daemon=True).start()

    def _init_session(self, sio: socketio.Client) -> None:
        command = {
            "cmd_type": int(CommandType.INIT),
            "clear_queue": False,
            "data": {**self.args, **({"robot_id": self.robot_id} if self.robot_id else {})},
        }
        try:
            ok, message = sio.call(COMMAND_EVENT, command, namespace=CONTROL_NAMESPACE, timeout=self.connect_timeout_s)
        except Exception as exc:
            log.warning("INIT failed: %s", exc)
            return
        if not ok:
            log.error("the netapp refused INIT: %s", message)
            self.stats.last_error = f"INIT refused: {message}"
            return
        self._encoder = None  # a new session decodes from a keyframe
        self.clock = ClockOffsetEstimator()  # a reconnect may reach another replica, with another clock
        self._connected.set()
        with self._cond:
            self._cond.notify_all()

    def _on_ws_disconnect(self, *reason: Any) -> None:
        self._connected.clear()
        with self._cond:
            lost = len(self._in_flight)
            self._in_flight.clear()
            self._cond.notify_all()
        if lost:
            self.stats.add(lost=lost)

    def _disconnect(self) -> None:
        self._connected.clear()
        if self._sio is not None:
            sio, self._sio = self._sio, None
            try:
                sio.disconnect()
            except Exception:
                pass
        if self.transport == "http" and self._session_id:
            try:
                requests.post(f"{self.url}/unregister", headers={"X-Session-Id": self._session_id}, timeout=2)
            except requests.RequestException:
                pass
            self._session_id = None
        with self._cond:
            lost = len(self._in_flight)
            self._in_flight.clear()
        if lost:
            self.stats.add(lost=lost)


def _json_or_text(response: requests.Response) -> dict[str, Any]:
    try:
        body = response.json()
        return body if isinstance(body, dict) else {"error": body}
    except ValueError:
        return {"error": response.text[:200]}
