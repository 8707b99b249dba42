"""`netapp stream --transport webrtc`: frames sent as a WebRTC video track (aiortc, the `webrtc` extra), for a robot
behind NAT or a TURN server; the results come back on a data channel as the `frames` transport's events
(docs/cameras.md#webrtc).

aiortc runs on an event loop in a thread of its own; `send()` only puts the newest frame in the track's slot (a frame
not yet taken by the encoder is replaced, and counted as dropped here), as the other transports' newest-wins ledger.
The session is the signalling's: one `POST /webrtc/offer` with every candidate in it (non-trickle), then the peer.

A result's `timestamp` is the picture's pts as aiortc's receiver gives it: the RTP timestamp less the first complete
picture's, so the frame's own pts (90 kHz, from the first frame sent) less the pts of the first frame the netapp got
whole. That is the first frame, unless it was lost: the offset is found once, as the one of the first frames' pts
that maps the first result onto a frame sent (pts follow the send times, so they do not repeat a pattern).
"""

from __future__ import annotations

import asyncio
import fractions
import logging
import queue
import threading
import time
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import requests

from netapp import wire_json
from netapp.client.delivery import Result
from netapp.client.errors import NetAppError
from netapp.client.stats import ClientStats
from netapp.client.transports import bearer_headers
from netapp.client.urls import http_url
from netapp.framing import ERROR_EVENT
from netapp.protocol import RESULTS_EVENT, error_message
from netapp.webrtc_ice import MISSING_MESSAGE, IceServer, configuration, restrict_host_addresses

log = logging.getLogger(__name__)

CLOCK_HZ = 90_000  # WebRTC video's RTP clock
ROUNDING_TICKS = (0, 1, -1, 2, -2)  # libvpx's 1/30000 s time base rounds a pts by a tick
FIRST_FRAMES = 64  # the frames one of which is the netapp's first whole picture
REMEMBERED = 512  # frames whose pts is kept to map results back
MAX_MESSAGE_CHARS = 4 * 1024 * 1024  # a data channel message from the netapp: longer ones are ignored
RESULTS_QUEUE = 1024


@dataclass(frozen=True)
class _Sending:
    full_frames: bool = False


@dataclass(frozen=True)
class _Options:
    """What `netapp.apps.streaming.stream` reads of a client's options."""

    sending: _Sending = field(default_factory=_Sending)


@dataclass
class _Sent:
    timestamp: int  # the frame's own (ns, the robot's clock)
    at: float  # time.monotonic() when the track gave it to the encoder


class WebRtcClient:
    """One netapp, one peer connection; the subset of `NetAppClient` that `netapp stream` uses."""

    codec = "webrtc"
    link_state = "webrtc"
    options = _Options()

    def __init__(
        self,
        url: str,
        *,
        token: str | None = None,
        robot_id: str | None = None,
        ice_servers: tuple[IceServer, ...] = (),
        ice_addresses: tuple[str, ...] = (),
        connect_timeout_s: float = 10.0,
        max_in_flight: int = 2,
    ) -> None:
        try:
            import aiortc  # noqa: F401
        except ImportError:
            raise NetAppError(MISSING_MESSAGE) from None
        self.url = http_url(url)
        self.urls = [self.url]
        self.token = token
        self.robot_id = robot_id
        self.max_in_flight = max_in_flight
        self.stats = ClientStats()
        self.session: str | None = None
        self._ice_servers = ice_servers
        self._ice_addresses = ice_addresses
        self._connect_timeout_s = connect_timeout_s
        self._results: queue.Queue[Result] = queue.Queue(RESULTS_QUEUE)
        self._sent: OrderedDict[int, _Sent] = OrderedDict()  # pts -> the frame
        self._lock = threading.Lock()
        self._first_pts: list[int] = []  # of the first FIRST_FRAMES frames sent
        self._offset: int | None = None  # the pts of the netapp's first picture
        self._last_result = time.monotonic()
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="netapp-webrtc", daemon=True)
        self._pc: Any = None
        self._track: Any = None
        self._connected = threading.Event()
        self._failed: str | None = None

    # -- the connection ---------------------------------------------------------------------------------------------

    def __enter__(self) -> WebRtcClient:
        self.connect()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def connect(self) -> None:
        """Offer, get the answer, wait until the peer is connected; NetAppError saying why not (the peer closed)."""
        self._thread.start()
        try:
            self._connect()
        except BaseException:
            self.close()
            raise

    def _connect(self) -> None:
        offer = self._run(self._offer())
        try:
            response = requests.post(
                f"{self.url}/webrtc/offer",
                json={"type": "offer", "sdp": offer, "robot_id": self.robot_id},
                headers=bearer_headers(self.token),
                timeout=self._connect_timeout_s,
            )
        except requests.RequestException as exc:
            raise NetAppError(f"cannot reach {self.url}: {type(exc).__name__}") from None
        try:
            body = response.json()
        except ValueError:
            body = None
        if not response.ok or not isinstance(body, dict) or not isinstance(body.get("sdp"), str):
            raise NetAppError(f"{self.url} refused the WebRTC offer: {error_message(body, response.reason)}")
        self.session = body.get("session")
        self._run(self._answer(body["sdp"]))
        if not self._connected.wait(self._connect_timeout_s) or self._failed:
            why = self._failed or f"not connected within {self._connect_timeout_s:g} s"
            raise NetAppError(f"the WebRTC peer to {self.url} failed: {why} (a NAT between? name a TURN server)")

    def _run(self, work: Any) -> Any:
        return asyncio.run_coroutine_threadsafe(work, self._loop).result(self._connect_timeout_s + 5)

    async def _offer(self) -> str:
        from aiortc import RTCPeerConnection

        restrict_host_addresses(self._ice_addresses)
        pc = self._pc = RTCPeerConnection(configuration(self._ice_servers))
        channel = pc.createDataChannel("results")
        channel.on("message", self._message)
        self._track = _LatestFrame(self)
        pc.addTrack(self._track)

        @pc.on("connectionstatechange")
        def changed() -> None:
            if pc.connectionState == "connected":
                self._connected.set()
            elif pc.connectionState in ("failed", "closed"):
                self._failed = self._failed or f"the connection is {pc.connectionState}"
                self._connected.set()

        await pc.setLocalDescription(await pc.createOffer())  # gathers every candidate first: non-trickle
        return pc.localDescription.sdp

    async def _answer(self, sdp: str) -> None:
        from aiortc import RTCSessionDescription

        await self._pc.setRemoteDescription(RTCSessionDescription(sdp=sdp, type="answer"))

    def close(self) -> None:
        if self._pc is not None and self._loop.is_running():
            try:
                self._run(self._pc.close())
            except Exception as exc:  # closing what may be broken already
                log.debug("closing the peer: %s", exc)
        if self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5)

    # -- frames -----------------------------------------------------------------------------------------------------

    def send(self, frame: np.ndarray) -> int:
        """Make `frame` (BGR) the next one the track gives the encoder; its timestamp (ns)."""
        if not isinstance(frame, np.ndarray):
            raise NetAppError("the webrtc transport sends decoded frames (arrays), not recorded bytes")
        timestamp = time.time_ns()
        with self.stats.lock:
            self.stats.offered += 1
            if self.stats.frame_size is None:
                self.stats.frame_size = (frame.shape[1], frame.shape[0])
        self._loop.call_soon_threadsafe(self._track.put, frame, timestamp)
        return timestamp

    def _took(self, pts: int, timestamp: int) -> None:
        """The track gave a frame to the encoder (on the loop)."""
        with self._lock:
            self._sent[pts] = _Sent(timestamp, time.monotonic())
            if len(self._first_pts) < FIRST_FRAMES:
                self._first_pts.append(pts)
            while len(self._sent) > REMEMBERED:
                self._sent.popitem(last=False)
        self.stats.add(sent=1)

    # -- results ----------------------------------------------------------------------------------------------------

    def _message(self, text: Any) -> None:
        if not isinstance(text, str) or len(text) > MAX_MESSAGE_CHARS:
            return
        try:
            message = wire_json.loads(text)
        except ValueError:
            return
        data = message.get("data") if isinstance(message, dict) else None
        if not isinstance(data, dict):
            return
        if message.get("event") == ERROR_EVENT:
            self.stats.add(errors=1)
            self.stats.last_error = str(data.get("error"))[:200]
            return
        if message.get("event") != RESULTS_EVENT:
            return
        sent = self._frame_of(data.get("timestamp"))
        now = time.monotonic()
        self._last_result = now
        detections = data.get("detections") if isinstance(data.get("detections"), list) else []
        if sent is None:  # a frame no longer remembered: a result all the same, its latency unknown
            result = Result(0, detections, float("nan"), data, source=self.url)
            self.stats.add(results=1)
        else:
            latency_ms = (now - sent.at) * 1000
            result = Result(sent.timestamp, detections, latency_ms, data, source=self.url)
            self.stats.add_result(latency_ms, detections, self.url)
        try:
            self._results.put_nowait(result)
        except queue.Full:
            self.stats.add(discarded=1)

    def _frame_of(self, timestamp: Any) -> _Sent | None:
        """The frame a result's `timestamp` names (see the module), None when it names none kept here."""
        if not isinstance(timestamp, int):
            return None
        with self._lock:
            if self._offset is None:
                self._offset = next((p for p in self._first_pts if self._near(timestamp + p)), None)
            return self._near(timestamp + self._offset) if self._offset is not None else None

    def _near(self, pts: int) -> _Sent | None:
        """The frame sent with `pts`, give or take the tick the encoder's own time base rounds away."""
        for step in ROUNDING_TICKS:
            found = self._sent.get(pts + step)
            if found is not None:
                return found
        return None

    def results(self, timeout: float | None = None) -> Iterator[Result]:
        """The results that arrived since the last call (waiting up to `timeout` for the first)."""
        try:
            yield self._results.get(timeout=timeout) if timeout else self._results.get_nowait()
        except queue.Empty:
            return
        while True:
            try:
                yield self._results.get_nowait()
            except queue.Empty:
                return

    def wait_idle(self, timeout_s: float) -> None:
        """Wait for the results of the frames sent (at most `timeout_s`): until one frame time passes with none
        after the last frame was taken."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                last_sent = next(reversed(self._sent.values())).at if self._sent else 0.0
            if self._last_result >= last_sent:
                return
            time.sleep(0.02)  # polling the result's arrival, with a deadline

    def processor_info(self) -> dict[str, Any] | None:
        try:
            response = requests.get(f"{self.url}/v2", headers=bearer_headers(self.token), timeout=2)
            models = response.json().get("models") if response.ok else None
        except (requests.RequestException, ValueError, AttributeError):
            return None
        return models[0] if isinstance(models, list) and models and isinstance(models[0], dict) else None

    def adapt_report(self) -> None:
        return None

    def transport_report(self) -> dict[str, Any]:
        """No transport counters here (`NetAppClient.transport_report`)."""
        return {}


class _LatestFrame:
    """The video track: gives the encoder the newest frame `send()` put here, waiting for one when none is new."""

    kind = "video"

    def __new__(cls, client: WebRtcClient) -> Any:
        from aiortc import MediaStreamTrack

        class Track(MediaStreamTrack):
            kind = "video"

            def __init__(self) -> None:
                super().__init__()
                self.slot: tuple[np.ndarray, int] | None = None
                self.ready = asyncio.Event()
                self.start: float | None = None
                self.last_pts: int | None = None

            def put(self, frame: np.ndarray, timestamp: int) -> None:
                if self.slot is not None:
                    client.stats.add(dropped_client=1)  # the encoder had not taken the one before
                self.slot = (frame, timestamp)
                self.ready.set()

            async def recv(self) -> Any:
                import av

                while self.slot is None:
                    self.ready.clear()
                    await self.ready.wait()
                (frame, timestamp), self.slot = self.slot, None
                now = time.monotonic()
                self.start = now if self.start is None else self.start
                pts = int((now - self.start) * CLOCK_HZ)
                if self.last_pts is not None and pts <= self.last_pts:
                    pts = self.last_pts + 1
                self.last_pts = pts
                picture = av.VideoFrame.from_ndarray(frame, format="bgr24")
                picture.pts = pts
                picture.time_base = fractions.Fraction(1, CLOCK_HZ)
                client._took(pts, timestamp)
                return picture

        return Track()
