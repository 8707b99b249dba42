"""The WebRTC peers of one app: each offer (`POST /webrtc/offer`, checked by `offer.check_offer`) becomes an aiortc
peer connection and a session (labelled `webrtc`: admitted, counted and shown on the live page as any robot's).

Its video track is read as fast as aiortc decodes it (aiortc queues decoded pictures without bound for a reader that
lags: that is the delay that builds up), and only the newest picture waits here, one slot per peer, one hand-off to
the pipeline at a time, as the RTSP cameras do (`netapp.server.sources.hub`); a picture replaced in the slot is
counted as skipped. Results and errors go back on the peer's data channel as the `frames` transport's text events
(`netapp.framing.event`), so a browser and a robot read the same JSON as on every other transport; a result also
goes on a channel that never resends, twice, where the peer opened one (`netapp stream` does: it takes the first
copy).
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import ipaddress
import logging
from dataclasses import dataclass, field
from typing import Any

from prometheus_client import Counter, Gauge

from netapp.framing import ERROR_EVENT, event
from netapp.protocol import RESULTS_EVENT, WEBRTC_COPY_CHANNEL
from netapp.rtp.packet import unwrap_timestamp
from netapp.rtp.results import compressed
from netapp.server.connection import Connection
from netapp.server.dataplane import DataPlane, IncomingFrame
from netapp.server.decoding.h264 import to_bgr
from netapp.server.decoding.image_limits import check_pixels
from netapp.server.errors import FrameError, FrameRejected, RequestRefused
from netapp.server.sessions import Session
from netapp.server.settings import Settings
from netapp.server.webrtc import jitter, nacks
from netapp.server.webrtc import offer as offers
from netapp.webrtc_ice import MISSING_MESSAGE, configuration, restrict_host_addresses

log = logging.getLogger(__name__)

LABEL = "webrtc"  # the `transport` label of WebRTC's frames and sessions
# The copy sent again this long after (in another SCTP packet): a result is lost only if both copies and the
# reliable channel's first sending are (0.003 % at 3 % loss each way, against 0.3 % with one copy, where the reliable
# channel's resending took 170 to 230 ms: the downlink of WebRTC's slowest frames, docs/benchmarks.md)
COPY_AGAIN_S = 0.005
MAX_BUFFERED_BYTES = 1 << 20  # results waiting in a data channel; past it a result is not sent (counted)
CLOSED_STATES = ("failed", "closed")
QUIET_LOGGERS = ("aioice", "aiortc")


class WebRtcMetrics:
    def __init__(self, registry: Any) -> None:
        r = registry
        self.refused = Counter(
            "netapp_webrtc_refused",
            "WebRTC offers refused (or peers that never connected), by reason: " + ", ".join(offers.REASONS),
            ["reason"],
            registry=r,
        )
        self.peers = Gauge("netapp_webrtc_peers", "WebRTC peer connections held", registry=r)
        self.skipped = Counter(
            "netapp_webrtc_skipped",
            "Pictures of WebRTC tracks replaced by a newer one before the model took them",
            registry=r,
        )
        self.held = Counter(
            "netapp_webrtc_held",
            "Pictures kept from the decoder until a keyframe: aiortc had dropped pictures they may refer to",
            registry=r,
        )
        self.candidates_dropped = Counter(
            "netapp_webrtc_candidates_dropped",
            "Remote ICE candidates never checked: at an address other than the offer's own (docs/security.md)",
            registry=r,
        )
        self.keyframes = Counter(
            "netapp_webrtc_keyframes", "Keyframes of WebRTC tracks released to the decoder", registry=r
        )
        self.nacked = Counter(
            "netapp_webrtc_nacked", "Packets of WebRTC tracks asked for again (RTCP NACK, each ask)", registry=r
        )
        self.recovered = Counter("netapp_webrtc_recovered", "Packets of WebRTC tracks asked for that came", registry=r)
        self.unsent = Counter(
            "netapp_webrtc_unsent", "Results not sent: the peer's data channel was closed or full", registry=r
        )
        for reason in offers.REASONS:
            self.refused.labels(reason=reason)


@dataclass(eq=False)
class Peer:
    """WebRTC's own part of a peer's `Connection` (its `wire`, `netapp.server.connection`): the peer connection, its
    data channel and the newest picture waiting. It ends with its session: the connection holds `pc.close`."""

    session: Session
    pc: Any  # aiortc.RTCPeerConnection
    client: str  # the address the offer came from
    channel: Any = None  # the first data channel the peer opened
    copy: Any = None  # one that never resends (maxRetransmits 0), if opened: each result on it too, compressed
    _slot: Any = None  # the newest decoded picture not yet handed to the pipeline
    _handing: bool = False
    _last_pts: int | None = None
    tasks: set[asyncio.Task] = field(default_factory=set)
    timer: asyncio.TimerHandle | None = None

    def timestamp(self, pts: int | None) -> int:
        """The picture's RTP timestamp (90 kHz), unwrapped past 32 bits: a result's `timestamp`."""
        self._last_pts = unwrap_timestamp(self._last_pts, int(pts or 0))
        return self._last_pts


class WebRtcPeers:
    """Every WebRTC peer of one app (a result sink for their sessions)."""

    def __init__(self, dataplane: DataPlane, settings: Settings) -> None:
        self.dataplane = dataplane
        self.settings = settings
        self.available = importlib.util.find_spec("aiortc") is not None
        self.metrics = WebRtcMetrics(dataplane.registry)
        self._closing: set[asyncio.Task] = set()  # peer connections being closed
        self._prepared = False
        self.metrics.peers.set_function(lambda: len(self.peers))
        if self.available:
            for name in QUIET_LOGGERS:  # a line per ICE check at INFO
                logging.getLogger(name).setLevel(max(logging.WARNING, logging.getLogger(name).level))
            dataplane.show_transport(LABEL)  # present at 0 from the start, as the other transports

    @property
    def peers(self) -> list[Peer]:
        """The peers held: the wire's part of each WebRTC connection (`DataPlane.connections`)."""
        return [c.wire for c in self.dataplane.connections(LABEL) if c.wire is not None and not c.closed]

    def _prepare(self) -> None:
        restrict_host_addresses(self.settings.webrtc_addresses)
        # a picture goes to the decoder at its last packet, not a frame interval later; none that refers to a lost one
        jitter.install(self.metrics.held.inc, self.metrics.keyframes.inc)
        # a lost packet asked for again at the measured round trip, a picture's lost end probed for
        nacks.install(self.metrics.nacked.inc, self.metrics.recovered.inc)
        import aiortc  # noqa: F401

        self._prepared = True

    def _refuse(self, reason: str, message: str, status: int, **extra: Any) -> RequestRefused:
        self.metrics.refused.labels(reason=reason).inc()
        return RequestRefused(reason, message, status, **extra)

    async def answer(self, body: Any, client: str) -> dict[str, Any]:
        """An offer (the request's JSON) from `client` -> the answer `{"type", "sdp", "session"}`; RequestRefused
        (counted) saying why not."""
        if not self.available:
            raise self._refuse(offers.NO_AIORTC, MISSING_MESSAGE, 501)
        settings = self.settings
        if not self._prepared:  # aiortc loads with the first offer (0.5 s, off the loop): unused, never imported
            await asyncio.to_thread(self._prepare)
        try:
            offer = offers.check_offer(body, settings.webrtc_max_sdp_bytes, offers.MAX_MEDIA)
        except RequestRefused as exc:
            self.metrics.refused.labels(reason=exc.reason).inc()
            raise
        sdp, dropped = offers.keep_candidates(offer.sdp, self._reachable(client))
        self.metrics.candidates_dropped.inc(dropped)
        if len(self.peers) >= settings.webrtc_max_peers:
            message = f"this netapp holds {settings.webrtc_max_peers} WebRTC peers (--webrtc-peers): try again later"
            raise self._refuse(offers.PEERS_FULL, message, 503, retry_after_s=5)
        if sum(1 for p in self.peers if p.client == client) >= settings.webrtc_max_peers_per_client:
            message = f"{client} holds {settings.webrtc_max_peers_per_client} WebRTC peers already: close one first"
            raise self._refuse(offers.CLIENT_PEERS_FULL, message, 429, retry_after_s=5)
        connection = Connection("", LABEL, self, host=client)
        session = self.dataplane.open_session(LABEL, offer.robot_id, {}, connection=connection)  # admitted as any
        from aiortc import RTCPeerConnection, RTCSessionDescription

        pc = RTCPeerConnection(configuration(settings.webrtc_ice_servers))
        peer = connection.wire = Peer(session, pc, client)
        connection.hold(lambda: self._release(peer))  # its peer connection goes with its session
        self._wire(peer)
        try:
            await pc.setRemoteDescription(RTCSessionDescription(sdp=sdp, type="offer"))
            await pc.setLocalDescription(await pc.createAnswer())  # gathers the (host) candidates: non-trickle
        except Exception as exc:  # aiortc's parser raises what it raises: the offer is the caller's doing
            self.dataplane.close_session(session, "its offer was refused")
            log.info("a WebRTC offer from %s was refused: %s", client, exc)
            raise self._refuse(offers.BAD_SDP, f"this offer cannot be answered: {str(exc)[:200]}", 400) from None
        peer.timer = asyncio.get_running_loop().call_later(settings.webrtc_connect_timeout_s, self._timeout, peer)
        return {"type": "answer", "sdp": pc.localDescription.sdp, "session": session.id}

    def _reachable(self, client: str) -> frozenset[str]:
        """The addresses whose ICE candidates are checked: the offer's own; from loopback, this machine's too."""
        own = offers.canonical_address(client)
        if own is None or not ipaddress.ip_address(own).is_loopback:
            return frozenset({own} if own else ())
        import aioice.ice

        local = getattr(aioice.ice.get_host_addresses, "__wrapped__", aioice.ice.get_host_addresses)(True, True)
        return frozenset({own, *(a for a in map(offers.canonical_address, local) if a)})

    def _wire(self, peer: Peer) -> None:
        pc = peer.pc

        @pc.on("track")
        def on_track(track: Any) -> None:
            if track.kind == "video" and not any(t.get_name() == "reader" for t in peer.tasks):
                self._bound(peer, track)
                self._spawn(peer, self._read(peer, track), "reader")

        @pc.on("datachannel")
        def on_datachannel(channel: Any) -> None:
            if channel.label == WEBRTC_COPY_CHANNEL and channel.maxRetransmits == 0 and peer.copy is None:
                peer.copy = channel
            elif peer.channel is None:
                peer.channel = channel

        @pc.on("connectionstatechange")
        async def on_state() -> None:
            if pc.connectionState == "connected" and peer.timer is not None:
                peer.timer.cancel()
                peer.timer = None
            elif pc.connectionState in CLOSED_STATES and not peer.session.closed:
                self.dataplane.close_session(peer.session, f"the WebRTC connection is {pc.connectionState}")

    def _bound(self, peer: Peer, track: Any) -> None:
        """The track's pictures over --max-pixels kept from aiortc's decoder (`jitter`), each refused to the peer."""
        for receiver in peer.pc.getReceivers():
            buffer = getattr(receiver, "_RTCRtpReceiver__jitter_buffer", None)  # aiortc keeps it private
            if receiver.track is track and hasattr(buffer, "bound"):
                buffer.bound(self.settings.max_pixels, lambda w, h, pts: self._too_large(peer, w, h, pts))

    def _too_large(self, peer: Peer, width: int, height: int, pts: int) -> None:
        """A picture whose header claims more than --max-pixels, never decoded: refused and counted as on every
        transport."""

        async def parse() -> IncomingFrame:
            check_pixels(width, height, self.settings.max_pixels, "this WebRTC picture")
            raise AssertionError("a picture over the bound is never taken")

        self._spawn(peer, self._submit(peer, peer.timestamp(pts), parse), "refusal")

    def _timeout(self, peer: Peer) -> None:
        peer.timer = None
        if peer.pc.connectionState != "connected" and not peer.session.closed:
            self.metrics.refused.labels(reason=offers.CONNECT_TIMEOUT).inc()
            log.info(
                "a WebRTC peer from %s did not connect within %.0f s",
                peer.client,
                self.settings.webrtc_connect_timeout_s,
            )
            self.dataplane.close_session(peer.session, "the WebRTC peer did not connect in time")

    # -- pictures: the track -> one slot -> the pipeline -------------------------------------------------------------

    async def _read(self, peer: Peer, track: Any) -> None:
        from aiortc.mediastreams import MediaStreamError

        while not peer.session.closed:
            try:
                picture = await track.recv()
            except MediaStreamError:
                return
            peer.session.touch()
            if peer._slot is not None:
                self.metrics.skipped.inc()
            peer._slot = picture
            if not peer._handing:
                peer._handing = True
                self._spawn(peer, self._hand_off(peer), "hand-off")

    async def _hand_off(self, peer: Peer) -> None:
        """Submit the newest picture, and again while a newer one came meanwhile."""
        try:
            while peer._slot is not None and not peer.session.closed:
                picture, peer._slot = peer._slot, None
                timestamp = peer.timestamp(picture.pts)

                async def parse(picture: Any = picture, timestamp: int = timestamp) -> IncomingFrame:
                    # WebRTC's edge: aiortc decoded it; converted on its lane, in order, as the pictures before it
                    check_pixels(picture.width, picture.height, self.settings.max_pixels, "this WebRTC picture")
                    return IncomingFrame.picture(timestamp, lambda: to_bgr(picture), in_order=True)

                await self._submit(peer, timestamp, parse)
        finally:
            peer._handing = False

    async def _submit(self, peer: Peer, timestamp: int, parse: Any) -> None:
        try:
            await self.dataplane.submit(peer.session, LABEL, parse, sink=self)
        except FrameRejected as exc:  # counted by the dataplane
            await self.error(peer.session, timestamp, exc)

    def _spawn(self, peer: Peer, work: Any, name: str) -> None:
        task = asyncio.ensure_future(work)
        task.set_name(name)
        peer.tasks.add(task)
        task.add_done_callback(peer.tasks.discard)

    # -- the result sink --------------------------------------------------------------------------------------------

    def _tell(self, session: Session, text: str, copy: bool = False) -> None:
        connection = self.dataplane.connection(session.id)
        peer = connection.wire if connection is not None else None
        channel = peer.channel if peer is not None else None
        if not _open(channel):
            self.metrics.unsent.inc()
            return
        if copy and _open(peer.copy):  # first: the reliable one may wait behind a loss. Compressed: one packet
            with contextlib.suppress(ValueError):  # (SCTP's chunks are lost one by one) and over the limit: none
                data = compressed(text.encode())
                peer.copy.send(data)
                asyncio.get_running_loop().call_later(COPY_AGAIN_S, _send_again, peer.copy, data)
        channel.send(text)

    async def result(self, session: Session, message: dict[str, Any]) -> None:
        # the picture's size beside the result (the /camera page draws on it: a browser may scale down what it sends)
        self._tell(session, event(RESULTS_EVENT, message, frame_size=session.frame_size), copy=True)

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None:
        self._tell(session, event(ERROR_EVENT, error.event(timestamp)))

    # -- the end ----------------------------------------------------------------------------------------------------

    def _release(self, peer: Peer) -> None:
        """The session ended (its peer went, timed out, the netapp stops): its peer connection is closed."""
        if peer.timer is not None:
            peer.timer.cancel()
        for task in list(peer.tasks):
            task.cancel()
        closing = asyncio.ensure_future(peer.pc.close())
        self._closing.add(closing)
        closing.add_done_callback(self._closing.discard)

    async def stop(self) -> None:
        for peer in self.peers:
            self.dataplane.close_session(peer.session, "the netapp is shutting down")
        if self._closing:
            with contextlib.suppress(Exception):
                await asyncio.wait(list(self._closing), timeout=5)


def _send_again(channel: Any, data: bytes) -> None:
    if _open(channel):
        channel.send(data)


def _open(channel: Any) -> bool:
    """Whether a result can go on this data channel now (open, not backed up)."""
    return channel is not None and channel.readyState == "open" and channel.bufferedAmount <= MAX_BUFFERED_BYTES
