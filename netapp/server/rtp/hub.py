"""The RTP sessions of one app: a UDP port each, its datagrams through the session's gate (`flow`) and the H.264
depacketiser (`netapp.rtp.depacketize`), each complete access unit submitted like a robot's H.264 frame (labelled
`rtp`, decoded by the session's own `H264Stream`), its result sent on the transport that opened the session.

A lost packet costs the pictures until the next keyframe, never a damaged picture: the depacketiser discards them,
and a keyframe is asked for at most every KEYFRAME_REQUEST_S, twice over: an RTCP PLI to the sender's RTCP port, and
an error event with reason `h264_missing_packet` on the session's transport (what the toolkit's own senders restart
their stream on, `netapp.protocol.H264_KEYFRAME_REASONS`). The same happens when the decoder refuses a picture.
A sender that asked for `results` gets each one over UDP as well, first (`send_result`): the transport's copy may wait
behind TCP's retransmissions on a lossy link.
"""

from __future__ import annotations

import asyncio
import logging
import secrets
import time
from dataclasses import dataclass, field
from typing import Any

from netapp import wire_json
from netapp.frame import H264, EncodedFrame
from netapp.protocol import H264_KEYFRAME_REASONS, RTP_TRANSPORT
from netapp.rtp.depacketize import AccessUnit, Depacketizer
from netapp.rtp.packet import RtpPacket, nack, pli, unwrap_timestamp
from netapp.rtp.reorder import Reorder
from netapp.rtp.results import result_datagram
from netapp.server.connection import Connection
from netapp.server.dataplane import DataPlane, IncomingFrame
from netapp.server.decoding.h264 import H264Decoder
from netapp.server.decoding.h264_bitstream import sps_sizes
from netapp.server.errors import FrameError, FrameRejected, RequestRefused
from netapp.server.pipeline.frame import ResultSink
from netapp.server.rtp.flow import Flow
from netapp.server.rtp.metrics import RtpMetrics
from netapp.server.rtp.ports import PortPool
from netapp.server.rtp.request import BAD_RTP_REASON, PORTS_FULL_REASON, RtpRequest, answer, parse_request
from netapp.server.sessions import Session
from netapp.server.settings import Settings

log = logging.getLogger(__name__)

LABEL = RTP_TRANSPORT  # the `transport` label of RTP's frames (present from the start: `NetAppServices`)
KEYFRAME_REQUEST_S = 0.25  # at most one keyframe request per this, per session: a keyframe takes a frame or two
# A picture begun and not finished this long is lost (its last packets, the marker's among them, were): a robot that
# waits for its answer before it sends the next picture would otherwise wait for its result timeout.
UNFINISHED_S = 0.2
MISSING = "h264_missing_packet"  # in H264_KEYFRAME_REASONS
MISSING_MESSAGE = (
    "RTP: this picture was skipped (its packets, or a picture before it, were lost); the netapp waits for the next "
    "keyframe and asked for one"
)


@dataclass(eq=False)
class RtpStream(asyncio.DatagramProtocol):
    """One session's port: RTP's own part of the `Connection` whose INIT (or `/register`) asked for it, which holds
    it (its port goes back when the session ends or the connection closes)."""

    hub: RtpSessions
    connection: Connection
    flow: Flow
    port: int
    depacketizer: Depacketizer
    h264: Any  # its H264Stream
    transport: asyncio.DatagramTransport | None = None
    _asked_at: float = -1e9
    _rtp_timestamp: int | None = None  # the last one, extended past 32 bits
    _tasks: set[asyncio.Task] = field(default_factory=set)
    _unfinished: asyncio.TimerHandle | None = None
    reorder: Reorder = field(default_factory=Reorder)
    _ticking: asyncio.TimerHandle | None = None

    @property
    def session(self) -> Session:
        session = self.connection.session
        assert session is not None, "an RTP stream opens with its session"
        return session

    @property
    def sink(self) -> ResultSink:
        return self.connection.sink or PollingSink(self.hub.dataplane)

    def connection_made(self, transport: Any) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr: Any) -> None:
        hub = self.hub
        hub.metrics.packets.inc()
        now = time.monotonic()
        packet = self.flow.admit(data, (addr[0], addr[1]), now)
        if isinstance(packet, str):
            hub.metrics.dropped.labels(reason=packet).inc()
            return
        ready, asked = self.reorder.push(packet, now)
        if ready is None:
            hub.metrics.dropped.labels(reason="late").inc()
            return
        self._nack(asked)
        self._depacketize(ready)

    def _depacketize(self, packets: list[RtpPacket]) -> None:
        self._count_recovery()
        for packet in packets:
            units, problems = self.depacketizer.push(packet)
            self._after(units, problems)
            for unit in units:
                self._submit(unit)
        self._watch_reorder()
        if self._unfinished is not None:
            self._unfinished.cancel()
            self._unfinished = None
        if self.depacketizer.gathering:
            self._unfinished = asyncio.get_running_loop().call_later(UNFINISHED_S, self._expire)

    def _count_recovery(self) -> None:
        """What the reorder buffer recovered, gave up, probed for and restarted since last time, into the metrics."""
        reorder, metrics = self.reorder, self.hub.metrics
        for waited in reorder.recovered:
            metrics.recovery.observe(waited)
        metrics.recovered.inc(len(reorder.recovered))
        metrics.given_up.inc(reorder.given_up)
        metrics.tail_probes.inc(reorder.probes)
        metrics.restarts.inc(reorder.restarts)
        reorder.recovered, reorder.given_up, reorder.probes, reorder.restarts = [], 0, 0, 0

    def _nack(self, sequences: list[int]) -> None:
        """Ask the sender for these packets again (RTCP generic NACK to its RTCP port)."""
        target = self.flow.rtcp_address()
        if sequences and target is not None and self.transport is not None:
            self.hub.metrics.nacked.inc(len(sequences))
            self.transport.sendto(nack(self.flow.ssrc ^ 1, self.flow.ssrc, sequences), target)

    def _watch_reorder(self) -> None:
        """A timer for the next gap to ask for again or give up (`Reorder.tick`)."""
        if self._ticking is not None:
            self._ticking.cancel()
            self._ticking = None
        deadline = self.reorder.next_deadline()
        if deadline is not None:
            delay = max(0.0, deadline - time.monotonic())
            self._ticking = asyncio.get_running_loop().call_later(delay, self._tick)

    def _tick(self) -> None:
        self._ticking = None
        ready, asked = self.reorder.tick(time.monotonic())
        self._nack(asked)
        self._depacketize(ready)

    def _expire(self) -> None:
        self._unfinished = None
        why = self.depacketizer.expire()
        self._after([], [why] if why else [])

    def _after(self, units: list[AccessUnit], problems: list[str]) -> None:
        """Count what the depacketiser discarded, ask for a keyframe, tell the robot of each skipped picture."""
        for why in problems:
            self.hub.metrics.dropped.labels(reason=why).inc()
        if self.depacketizer.need_keyframe and (problems or units):
            self.ask_keyframe()
        skipped, self.depacketizer.discarded = self.depacketizer.discarded, []
        for rtp_timestamp in skipped:
            # A picture the robot sent, skipped: it hears so, as for any frame (its slot freed, its encoder told to
            # restart with a keyframe: the reason is one of H264_KEYFRAME_REASONS).
            timestamp = self._timestamp(rtp_timestamp)
            self._spawn(self.sink.error(self.session, timestamp, FrameRejected(MISSING, MISSING_MESSAGE)))

    def send_result(self, message: dict[str, Any]) -> None:
        """A copy of a result over UDP (`netapp.rtp.results`) to a sender that asked for one (`results`): the robot
        takes the first copy to arrive. One that does not fit in a datagram goes on the session's transport only."""
        target = self.flow.rtcp_address()
        if not self.flow.request.results or target is None or self.transport is None:
            return
        try:
            datagram = result_datagram(self.flow.ssrc ^ 1, wire_json.dumpb(message))
        except (TypeError, ValueError):  # too large (or not JSON: the transport's copy says so)
            self.hub.metrics.results_udp.labels(outcome="too_large").inc()
            return
        self.hub.metrics.results_udp.labels(outcome="sent").inc()
        self.transport.sendto(datagram, target)

    def error_received(self, exc: Exception) -> None:  # an ICMP error for a PLI we sent: the sender is gone
        log.debug("RTP session %s: %s", self.session.id, exc)

    def ask_keyframe(self) -> None:
        """An RTCP PLI to the sender, rate-limited (the robot hears of each skipped picture on its transport)."""
        now = time.monotonic()
        if now - self._asked_at < KEYFRAME_REQUEST_S:
            return
        self._asked_at = now
        self.hub.metrics.keyframe_requests.inc()
        target = self.flow.rtcp_address()
        if target is not None and self.transport is not None:
            self.transport.sendto(pli(self.flow.ssrc ^ 1, self.flow.ssrc), target)

    def _timestamp(self, rtp_timestamp: int) -> int:
        """The RTP timestamp, unwrapped (results carry it as their `timestamp`)."""
        self._rtp_timestamp = unwrap_timestamp(self._rtp_timestamp, rtp_timestamp)
        return self._rtp_timestamp

    def _submit(self, unit: AccessUnit) -> None:
        self.session.touch()  # a robot that only streams (and polls rarely, over HTTP) is still there
        frame = access_unit_frame(unit, self._timestamp(unit.rtp_timestamp))
        timestamp = frame.timestamp

        async def parse() -> IncomingFrame:
            decode = self.h264.frame(frame)  # queued now, in arrival order
            return IncomingFrame(frame, decode, in_order=True)

        async def submit() -> None:
            try:
                await self.hub.dataplane.submit(self.session, LABEL, parse, sink=self.sink_for_errors)
            except FrameRejected as exc:  # counted by the dataplane
                await self.sink_for_errors.error(self.session, timestamp, exc)

        self._spawn(submit())

    def _spawn(self, work: Any) -> None:
        task = asyncio.ensure_future(work)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    @property
    def sink_for_errors(self) -> _KeyframeAsking:
        return _KeyframeAsking(self)

    def close(self) -> None:
        for timer in (self._unfinished, self._ticking):
            if timer is not None:
                timer.cancel()
        if self.transport is not None:
            self.transport.close()
        self.h264.close()
        for task in list(self._tasks):
            task.cancel()


def access_unit_frame(unit: AccessUnit, timestamp: int) -> EncodedFrame:
    """RTP's edge: a complete access unit -> its frame (a keyframe's picture size read from its SPS, so that its
    decoder opens at it)."""
    width = height = 0
    if unit.keyframe:
        try:
            sizes = list(sps_sizes(unit.data))
        except ValueError:
            sizes = []
        if sizes:
            width, height = sizes[0]
    return EncodedFrame(H264, timestamp, unit.data, width, height)


@dataclass(frozen=True)
class PollingSink:
    """An HTTP robot's results and errors, kept for it to poll (`GET /results`), as for its POSTed frames."""

    dataplane: DataPlane

    async def result(self, session: Session, message: dict[str, Any]) -> None:
        self.dataplane.keep(session, message)

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None:
        self.dataplane.keep(session, error.event(timestamp))


@dataclass(frozen=True)
class _KeyframeAsking:
    """The session's transport sink, asking for a keyframe too when the decoder lost the stream."""

    stream: RtpStream

    async def result(self, session: Session, message: dict[str, Any]) -> None:
        self.stream.send_result(message)  # first: a datagram goes now, the transport's copy may wait behind TCP
        await self.stream.sink.result(session, message)

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None:
        if error.reason in H264_KEYFRAME_REASONS:
            self.stream.depacketizer.need_keyframe = True  # the decoder waits for one: so does the depacketiser
            self.stream.ask_keyframe()
        await self.stream.sink.error(session, timestamp, error)


class RtpSessions:
    """Every RTP session of one app (none unless `--rtp-ports` names a range)."""

    def __init__(self, dataplane: DataPlane, settings: Settings, h264: H264Decoder) -> None:
        self.dataplane = dataplane
        self.settings = settings
        self.h264 = h264
        self.pool = PortPool(settings.rtp_ports) if settings.rtp_ports else None
        self.metrics = RtpMetrics(dataplane.registry)
        self.streams: dict[str, RtpStream] = {}  # by session id
        for reason in (BAD_RTP_REASON, PORTS_FULL_REASON):
            self.metrics.refused.labels(reason=reason)
        if self.pool is not None:
            self.metrics.ports_free.set_function(lambda: self.pool.free if self.pool else 0)

    @property
    def enabled(self) -> bool:
        return self.pool is not None

    def check(self, value: Any) -> RtpRequest:
        """A session's `rtp` argument, checked before its session opens; RequestRefused (counted) saying why not."""
        why = None
        if self.pool is None:
            why = "this netapp takes no RTP: start it with --rtp-ports FIRST-LAST (e.g. 50000-50099)"
        elif self.h264.unavailable is not None:
            why = self.h264.unavailable
        else:
            try:
                return parse_request(value)
            except ValueError as exc:
                why = str(exc)
        self.metrics.refused.labels(reason=BAD_RTP_REASON).inc()
        raise RequestRefused(BAD_RTP_REASON, why, 422)

    async def open(self, connection: Connection, request: RtpRequest) -> dict[str, Any]:
        """Bind a port for the connection's session (its request `check`ed), held by the connection; the answer the
        robot needs (`request.answer`). RequestRefused 503 when no port is free."""
        assert self.pool is not None and connection.session is not None
        session_id = connection.session.id
        h264 = self.h264.open()
        settings = self.settings
        loop = asyncio.get_running_loop()
        ssrc = secrets.randbits(32)
        for port in self.pool.candidates():
            flow = Flow(request, ssrc, settings.rtp_max_packets_per_s, settings.rtp_max_bytes_per_s)
            stream = RtpStream(self, connection, flow, port, Depacketizer(settings.max_payload_bytes), h264)
            try:
                await loop.create_datagram_endpoint(lambda s=stream: s, local_addr=(settings.rtp_host, port))
            except OSError:  # taken by another process: try the next one
                continue
            self.pool.hold(port)
            self.streams[session_id] = stream
            connection.hold(lambda: self.close(session_id))  # its port goes with its session, however that ends
            return answer(request, connection.host, port, ssrc)
        h264.close()
        self.metrics.refused.labels(reason=PORTS_FULL_REASON).inc()
        log.warning("an RTP session was refused: every port of %s is held", _shown(self.pool.ports))
        why = f"no RTP port of {_shown(self.pool.ports)} is free: try again when a session ends"
        raise RequestRefused(PORTS_FULL_REASON, why, 503, retry_after_s=5)

    def close(self, session_id: str) -> None:
        """The session ended: its port is closed and returned."""
        stream = self.streams.pop(session_id, None)
        if stream is not None:
            stream.close()
            assert self.pool is not None
            self.pool.give_back(stream.port)

    def stop(self) -> None:
        for session_id in list(self.streams):
            self.close(session_id)


def _shown(ports: range) -> str:
    return f"--rtp-ports {ports.start}-{ports.stop - 1}"
