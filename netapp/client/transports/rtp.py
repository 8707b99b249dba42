"""The `rtp` transport: H.264 over RTP/UDP to a session opened on the `frames` WebSocket (docs/cameras.md#rtp-push).

The session, its commands and its results are the frames transport's (INIT asks for `rtp`; the ack answers the port
and the SSRC to send with); only the frames go another way: each H.264 access unit is cut into RTP packets by the
project's own packetiser (`netapp.rtp.packetize`, RFC 6184 mode 1) and sent in UDP datagrams, so a lost packet
costs the pictures until the next keyframe and holds nothing behind it, as TCP would. PyAV encodes, as for the other
H.264 transports (one encoder, `netapp.client.h264`), rather than a gst-launch subprocess: the client already has the
frames as arrays, sends each one when the newest-wins ledger says so, and needs no system package.

A result's `timestamp` is the RTP timestamp the netapp saw (90 kHz, unwrapped); it is mapped back to the frame's own
here. When the netapp lost packets it says so on the WebSocket (`h264_missing_packet`, one of
`H264_KEYFRAME_REASONS`): the H.264 encoder restarts with a keyframe, as it does on the other transports. It also
sends RTCP to this socket (rtcp-mux): a generic NACK names packets it missed, which are sent again from the last
RESEND_PACKETS kept here, so most losses cost a round trip rather than the pictures until a keyframe; a PLI needs
nothing more here (the skipped pictures' errors restart the encoder).

Results come back over UDP too (INIT asks for `results`): each in an RTCP APP packet on this socket, as well as on
the WebSocket; the first copy to arrive is the result, the other is dropped here. Over a lossy link a result on the
WebSocket waits for TCP to resend what was lost before it (hundreds of ms at the tail); its datagram does not.
"""

from __future__ import annotations

import logging
import socket
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any
from urllib.parse import urlsplit

from websockets.sync.client import ClientConnection

from netapp import wire_json
from netapp.client.errors import ConnectionLost, NetAppError
from netapp.client.transports import SessionSettings, TransportCallbacks
from netapp.client.transports.frames import FramesTransport
from netapp.client.transports.rtp_answers import Answers
from netapp.frame import H264, EncodedFrame
from netapp.frames_session import Acked
from netapp.protocol import RTP_TRANSPORT, CommandType
from netapp.rtp.packet import DEFAULT_PAYLOAD_TYPE, H264_CLOCK_HZ, build, is_pli, parse_nack
from netapp.rtp.packetize import payloads
from netapp.rtp.results import result_json

RTP_ARG = RTP_TRANSPORT  # INIT's argument and its ack's answer (`netapp.server.rtp.request.RTP_FIELD`)
READ_TIMEOUT_S = 0.5
RESEND_PACKETS = 2048  # the last packets sent, kept to send again when the netapp asks (NACK): a few 720p keyframes

log = logging.getLogger(__name__)


@dataclass
class RtpCounters:
    """What the robot's side of an RTP session did (`netapp stream` prints them: a round without a result says why).
    Plain integers, each written by one thread."""

    packets: int = 0  # RTP packets sent (the sender's thread)
    nacked: int = 0  # packets the netapp asked for again (the UDP reader)
    resent: int = 0  # of those, sent again (the others were no longer kept)
    plis: int = 0  # keyframe requests (RTCP PLI) from the netapp
    results_udp: int = 0  # results delivered from their datagram
    results_websocket: int = 0  # results delivered from the WebSocket (their datagram lost, or later)
    reader_error: str | None = None  # the last exception the UDP reader caught (a bug: it goes on)


class RtpTransport(FramesTransport):
    """A frames session whose H.264 frames go over RTP."""

    udp_socket = staticmethod(socket.socket)  # how its UDP socket is made (a test puts a lossy link here)

    def __init__(self, url: str, settings: SessionSettings, callbacks: TransportCallbacks) -> None:
        args = {**settings.args, RTP_ARG: {"payload_type": DEFAULT_PAYLOAD_TYPE, "rtcp_mux": True, "results": True}}
        self._answer_book = Answers()  # under _lock
        self._lock = threading.Lock()
        self._delivering = threading.RLock()  # results come from two threads (WebSocket, UDP): one at a time
        self._udp: socket.socket | None = None
        self._target: tuple[str, int] | None = None
        self._ssrc = 0
        self._payload_type = DEFAULT_PAYLOAD_TYPE
        self._sequence = 0
        self._sent: OrderedDict[int, bytes] = OrderedDict()  # sequence -> packet, the last RESEND_PACKETS
        self._callbacks = callbacks
        self.counters = RtpCounters()
        mapped = replace(
            callbacks,
            on_result=lambda message: self._from_websocket(message, callbacks.on_result, result=True),
            on_error=lambda message: self._from_websocket(message, callbacks.on_error),
            on_dropped=self._dropped_frame,
        )
        super().__init__(url, replace(settings, args=args), mapped)

    def _command(self, ws: ClientConnection, cmd_type: CommandType, data: Any) -> Acked:
        answer = super()._command(ws, cmd_type, data)
        if cmd_type == CommandType.INIT and answer.ok:
            self._begin(answer.answer.get(RTP_ARG))
        return answer

    def _begin(self, rtp: Any) -> None:
        """A new session's port and SSRC (each INIT, again after a reconnect: a new session, a new port)."""
        if not isinstance(rtp, dict) or not isinstance(rtp.get("port"), int) or not isinstance(rtp.get("ssrc"), int):
            raise NetAppError(f"{self.url} did not answer INIT with an RTP port: is it a netapp with --rtp-ports?")
        host = urlsplit(self.url).hostname or "127.0.0.1"
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        old, self._udp = self._udp, self.udp_socket(family, socket.SOCK_DGRAM)
        if old is not None:
            old.close()
        self._target = (host, rtp["port"])
        self._ssrc, self._payload_type = rtp["ssrc"], int(rtp.get("payload_type", DEFAULT_PAYLOAD_TYPE))
        with self._lock:
            self._answer_book.clear()
            self._sent.clear()
        reader = threading.Thread(target=self._read_rtcp, args=(self._udp,), name="netapp-rtcp", daemon=True)
        reader.start()

    def transmit(self, frame: EncodedFrame) -> None:
        if frame.codec != H264:
            raise ValueError("the rtp transport carries H.264: use codec='h264' (netapp stream --transport rtp)")
        udp, target = self._udp, self._target
        if udp is None or target is None or not self._ready:
            raise ConnectionLost("the rtp session is down")
        timestamp = frame.timestamp
        rtp_timestamp = (timestamp * H264_CLOCK_HZ // 1_000_000_000) & 0xFFFFFFFF
        with self._lock:
            self._answer_book.sent(rtp_timestamp, timestamp)
        pieces = list(payloads(frame.payload))  # the frame's edge: its access unit in RTP packets
        try:
            for i, piece in enumerate(pieces):
                packet = build(
                    piece,
                    payload_type=self._payload_type,
                    sequence=self._sequence,
                    timestamp=rtp_timestamp,
                    ssrc=self._ssrc,
                    marker=i == len(pieces) - 1,
                )
                with self._lock:
                    self._sent[self._sequence] = packet
                    if len(self._sent) > RESEND_PACKETS:
                        self._sent.popitem(last=False)
                self._sequence = (self._sequence + 1) & 0xFFFF
                udp.sendto(packet, target)
                self.counters.packets += 1
        except OSError as exc:  # a full socket buffer, no route: the frame is lost as on a lossy link
            raise ConnectionLost(f"RTP to {target[0]}:{target[1]}: {exc}") from exc

    def _read_rtcp(self, udp: Any) -> None:
        """What the netapp sends back on this socket (rtcp-mux): a NACK's packets are sent again, a result is
        delivered (unless its WebSocket copy came first); the thread ends with its socket."""
        target, ssrc = self._target, self._ssrc
        udp.settimeout(READ_TIMEOUT_S)  # a closed socket does not wake a blocked read: look again this often
        while udp is self._udp:
            try:
                data, _ = udp.recvfrom(2048)
            except TimeoutError:
                continue
            except OSError:  # closed: a new session, or the client closing
                return
            try:
                if not self._feedback(udp, data, target, ssrc):
                    return
            except Exception as exc:  # a bug, not the network's: said and counted, the session's UDP goes on
                log.exception("the RTP transport's UDP reader failed on a datagram from the netapp")
                self.counters.reader_error = f"{type(exc).__name__}: {exc}"

    def _feedback(self, udp: Any, data: bytes, target: tuple[str, int] | None, ssrc: int) -> bool:
        """One datagram from the netapp (a result, a NACK, a PLI); False when the socket is closed."""
        result = result_json(data, ssrc ^ 1)  # the netapp's SSRC (the session's token): anyone else's is ignored
        if result is not None:
            self._udp_result(result)
            return True
        if is_pli(data):  # the skipped pictures' errors restart the encoder (on the WebSocket)
            self.counters.plis += 1
            return True
        for sequence in parse_nack(data):
            self.counters.nacked += 1
            with self._lock:
                packet = self._sent.get(sequence)
            if packet is not None and target is not None:
                try:
                    udp.sendto(packet, target)
                except OSError:
                    return False
                self.counters.resent += 1
        return True

    def _udp_result(self, data: bytes) -> None:
        """A result's datagram: delivered with its frame's own timestamp, unless that frame was answered already.
        Every byte is the network's: anything but a result object for a frame sent here is ignored."""
        try:
            message = wire_json.loads(data)
        except ValueError:
            return
        rtp_timestamp = message.get("timestamp") if isinstance(message, dict) else None
        if not isinstance(rtp_timestamp, int) or isinstance(rtp_timestamp, bool):
            return
        with self._delivering:
            with self._lock:
                timestamp = self._answer_book.from_datagram(rtp_timestamp)
            if timestamp is not None:
                self.counters.results_udp += 1
                self._callbacks.on_result({**message, "timestamp": timestamp})

    def _dropped_frame(self, rtp_timestamp: Any) -> None:
        """A frame the netapp's queue superseded (newest wins): told with its own timestamp, forgotten here."""
        with self._delivering:
            if isinstance(rtp_timestamp, int) and not isinstance(rtp_timestamp, bool):
                with self._lock:
                    timestamp = self._answer_book.superseded(rtp_timestamp)
                rtp_timestamp = rtp_timestamp if timestamp is None else timestamp
            self._callbacks.on_dropped(rtp_timestamp)

    def _from_websocket(
        self, message: dict[str, Any], deliver: Callable[[dict[str, Any]], None], result: bool = False
    ) -> None:
        """A result or error from the WebSocket, with its frame's own timestamp; not delivered again when its
        datagram came first; the frames before a result that got no answer told as dropped (`rtp_answers`)."""
        rtp_timestamp = message.get("timestamp")
        with self._delivering:
            if not isinstance(rtp_timestamp, int) or isinstance(rtp_timestamp, bool):
                deliver(message)
                return
            with self._lock:
                answer = self._answer_book.from_websocket(rtp_timestamp, result)
            for dropped in answer.dropped:
                self._callbacks.on_dropped(dropped)
            if answer.deliver:
                self.counters.results_websocket += result
                deliver(message if answer.timestamp is None else {**message, "timestamp": answer.timestamp})

    def report(self) -> dict[str, Any]:
        """Its counters (`RtpCounters`), for the stream's summary."""
        return asdict(self.counters)

    def close(self) -> None:
        super().close()
        udp, self._udp = self._udp, None
        if udp is not None:
            udp.close()
