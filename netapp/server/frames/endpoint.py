"""The `frames` WebSocket endpoint: a raw ASGI app at `FRAMES_PATH`, a thin layer over the dataplane.

One WebSocket per robot session (on one replica, as Socket.IO's): text messages are commands (INIT first, then the
state commands; `netapp.server.commands`, as on Socket.IO's /control), binary messages are frames
(`netapp.framing`). Results and errors are pushed back as text events by this endpoint, the result sink of its
frames. Every message is hostile: uvicorn closes a connection whose message is over `ws_max_size` (1009) before
reading it; a bad message gets one `error` event and is counted; the connection goes on. No or a wrong token, or a
draining replica, is told why (`refused`) and closed (1008, 1013).
"""

from __future__ import annotations

import logging
import time
from typing import Any

from netapp.framing import (
    ACK_EVENT,
    CLOSE_POLICY,
    CLOSE_TRY_AGAIN,
    CODECS,
    ERROR_EVENT,
    REFUSED_EVENT,
    WireError,
    event,
    parse_frame,
    parse_text,
)
from netapp.protocol import (
    DRAINING_REASON,
    FORWARDED_HEADER,
    FRAMES_H264_LABEL,
    FRAMES_TRANSPORT,
    MOVE_EVENT,
    RESULTS_EVENT,
    SESSION_INFO_EVENT,
    UNAUTHORIZED_REASON,
    CommandType,
    error_body,
    error_event,
)
from netapp.server import access
from netapp.server.asgi_scope import header
from netapp.server.commands import Commands
from netapp.server.dataplane import DataPlane, IncomingFrame
from netapp.server.decoding.decoder import FrameDecoder
from netapp.server.decoding.h264 import H264Decoder
from netapp.server.decoding.jpeg import JpegDecoder
from netapp.server.errors import FrameError, FrameRejected
from netapp.server.frames.connection import LOW_WATER, FramesConnection
from netapp.server.rtp.hub import RtpSessions, asks_rtp
from netapp.server.rtp.request import RTP_FIELD
from netapp.server.sessions import Session
from netapp.server.sources.hub import Sources, watch_answer
from netapp.tracecontext import TRACEPARENT, TRACESTATE

log = logging.getLogger(__name__)

LABELS = {CODECS["jpeg"]: FRAMES_TRANSPORT, CODECS["h264"]: FRAMES_H264_LABEL}  # codec byte -> metrics label


class FramesEndpoint:
    """The ASGI app of `/frames`, and the result sink (`pipeline.frame.ResultSink`) of the frames it receives."""

    def __init__(
        self, dataplane: DataPlane, h264: H264Decoder, sources: Sources | None = None, rtp: RtpSessions | None = None
    ) -> None:
        self.dataplane = dataplane
        self.sources = sources  # the cameras it pulls, whose results a connection may WATCH
        self.rtp = rtp  # sessions whose H.264 comes over RTP (INIT's `rtp`), their results sent here
        self.settings = dataplane.settings
        self.commands = Commands(dataplane, FRAMES_TRANSPORT)
        self.jpeg = JpegDecoder(self.settings.max_pixels)
        self.h264 = h264
        self.connections: dict[str, FramesConnection] = {}  # by session key

    # -- the connection -----------------------------------------------------------------------------------------

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if (await receive())["type"] != "websocket.connect":
            return
        await send({"type": "websocket.accept"})
        query = scope.get("query_string", b"").decode("latin-1")  # any bytes at all: never a decoding error
        host = (scope.get("server") or ("127.0.0.1", 0))[0]  # where the robot reached us: where its RTP goes
        token = access.connection_token(header(scope, b"authorization"), query)
        granted = access.granted_class(self.settings, token)
        if granted is None:
            why = "this netapp needs a token: send Authorization: Bearer TOKEN (the middleware gives it with the URL)"
            return await self._refuse(send, error_body(why, UNAUTHORIZED_REASON), CLOSE_POLICY)
        if self.dataplane.services.draining:
            why = "this replica is draining: connect again through the Service"
            return await self._refuse(send, error_body(why, DRAINING_REASON, retry_after_s=1), CLOSE_TRY_AGAIN)
        connection = FramesConnection(send, granted, self.dataplane.services.metrics.results_overflowed.inc)
        connection.token, connection.forwarded = token, header(scope, FORWARDED_HEADER.lower().encode()) is not None
        self.connections[connection.key] = connection
        connection.start()
        try:
            while True:
                message = await receive()
                if message["type"] != "websocket.receive":
                    break  # websocket.disconnect
                data = message.get("bytes")
                if data is not None:
                    await self.on_frame(connection, data)
                else:
                    await self.on_text(connection, message.get("text") or "", host)
                if len(connection.unsent) >= LOW_WATER:  # the robot does not read its answers: read no more of it
                    await connection.room()
        finally:
            self.close(connection)

    async def _refuse(self, send: Any, body: dict[str, Any], code: int) -> None:
        await send({"type": "websocket.send", "text": event(REFUSED_EVENT, body)})
        await send({"type": "websocket.close", "code": code, "reason": body["reason"]})

    def close(self, connection: FramesConnection) -> None:
        """The robot went away: close its decoder and its session."""
        connection.stop()
        self.connections.pop(connection.key, None)
        if self.sources is not None:
            self.sources.unsubscribe(connection.watcher)
        if connection.h264 is not None:
            connection.h264.close()
        session = self.dataplane.services.sessions.get(connection.key)
        if session is not None:
            self.dataplane.close_session(session, "the robot disconnected")

    def move_all(self, notice: dict[str, Any]) -> None:
        """A draining replica: every robot here is told to reconnect through the Service."""
        for connection in list(self.connections.values()):
            connection.tell(event(MOVE_EVENT, notice))

    # -- commands -------------------------------------------------------------------------------------------------

    async def on_text(self, connection: FramesConnection, text: str, host: str = "127.0.0.1") -> None:
        try:
            command = parse_text(text, self.settings.transport_limit_bytes)
        except WireError as exc:
            self.dataplane.refuse(FRAMES_TRANSPORT, exc.reason)
            connection.tell(event(ERROR_EVENT, error_event(None, str(exc), exc.reason)))
            return
        decoders = [connection.h264] if connection.h264 is not None else []
        extra: dict[str, Any] = {}
        if command.get("cmd_type") == CommandType.WATCH:
            ok, message, refused = watch_answer(
                self.sources, command, connection.watcher, connection.token, connection.forwarded
            )
        elif self.rtp is not None and asks_rtp(command):

            async def init() -> tuple[bool, str, dict[str, Any]]:
                return await self.commands.execute(connection.key, command, granted=connection.granted)

            ok, message, refused, answer = await self.rtp.init(connection.key, command, init, self, host)
            extra = {RTP_FIELD: answer} if answer is not None else {}
        else:
            ok, message, refused = await self.commands.execute(
                connection.key, command, granted=connection.granted, decoders=decoders
            )
        if ok and command.get("cmd_type") == CommandType.INIT:  # what the robot needs before its first frame
            connection.tell(event(SESSION_INFO_EVENT, self.dataplane.session_info()))
        if not ok:
            self.dataplane.refuse(FRAMES_TRANSPORT, "bad_command")
        answer = {"id": command.get("id"), "ok": ok, "message": message, "session_id": connection.key, **refused}
        answer.update(extra)
        connection.tell(event(ACK_EVENT, **answer))

    # -- frames ---------------------------------------------------------------------------------------------------

    async def on_frame(self, connection: FramesConnection, data: bytes) -> None:
        recv_ns = time.monotonic_ns()
        session = self.dataplane.services.sessions.get(connection.key)
        label = LABELS.get(data[1] if len(data) > 1 else 0, FRAMES_TRANSPORT)
        timestamp: int | None = None

        async def parse() -> IncomingFrame:
            nonlocal timestamp
            if session is None:
                raise FrameRejected("no_session", "send the INIT command (a text message) before sending frames")
            try:
                frame = parse_frame(data)
            except WireError as exc:
                raise FrameRejected(exc.reason, str(exc)) from None
            timestamp = frame.timestamp
            limit = self.settings.max_payload_bytes
            if len(frame.payload) > limit:
                raise FrameRejected("payload_too_large", f"frame of {len(frame.payload)} bytes is over {limit}")
            message: dict[str, Any] = {"timestamp": frame.timestamp, "frame": frame.payload}
            if frame.width or frame.height:
                message.update(width=frame.width, height=frame.height)
            decoder = self._decoder(connection, frame.codec)
            decode = decoder.frame(message)
            meta = frame.meta or {}
            return IncomingFrame(
                frame.timestamp,
                decode,
                frame.deadline_ms,
                robot_latency=meta.get("latency"),
                size_bytes=len(frame.payload),
                in_order=decoder.in_order,
                traceparent=meta.get(TRACEPARENT),
                tracestate=meta.get(TRACESTATE),
            )

        try:
            await self.dataplane.submit(session, label, parse, recv_ns=recv_ns, sink=self)
        except FrameRejected as exc:  # counted by the dataplane
            connection.tell(event(ERROR_EVENT, exc.event(timestamp)))

    def _decoder(self, connection: FramesConnection, codec: str) -> FrameDecoder:
        if codec == "jpeg":
            return self.jpeg
        if connection.h264 is None:
            connection.h264 = self.h264.open()
        return connection.h264

    # -- the result sink ------------------------------------------------------------------------------------------

    async def result(self, session: Session, message: dict[str, Any]) -> None:
        connection = self.connections.get(session.id)
        if connection is not None:
            connection.tell(event(RESULTS_EVENT, message))

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None:
        connection = self.connections.get(session.id)
        if connection is not None:
            connection.tell(event(ERROR_EVENT, error.event(timestamp)))
