"""The `frames` WebSocket endpoint: a raw ASGI app at `FRAMES_PATH`, a thin layer over the dataplane.

One WebSocket per robot session (on one replica, as Socket.IO's), one `Connection` (`netapp.server.connection`)
whose wire part is its `FramesWire`: text messages are commands (INIT first, then the state commands; the one
dispatch, `netapp.server.commands`, as on Socket.IO's /control), binary messages are frames (`netapp.framing`
parses each into an `EncodedFrame`, which its connection's decoder takes). Results and errors are pushed back as
text events by this endpoint, the result sink of its frames. Every message is hostile: uvicorn closes a connection
whose message is over `ws_max_size` (1009) before reading it; a bad message gets one `error` event and is counted;
the connection goes on. No or a wrong token, or a draining replica, is told why (`refused`) and closed (1008, 1013).
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
    error_body,
    error_event,
)
from netapp.server import access
from netapp.server.asgi_scope import header
from netapp.server.commands import Commands
from netapp.server.connection import Connection
from netapp.server.dataplane import DataPlane, IncomingFrame
from netapp.server.decoding.h264 import H264Decoder
from netapp.server.errors import FrameError, FrameRejected
from netapp.server.frames.connection import LOW_WATER, FramesWire
from netapp.server.frames.decoding import FrameDecoding
from netapp.server.rtp.request import RTP_FIELD
from netapp.server.sessions import Session
from netapp.server.settings import Settings

log = logging.getLogger(__name__)

LABELS = {CODECS["jpeg"]: FRAMES_TRANSPORT, CODECS["h264"]: FRAMES_H264_LABEL}  # codec byte -> metrics label


class FramesEndpoint:
    """The ASGI app of `/frames`, and the result sink (`pipeline.frame.ResultSink`) of the frames it receives."""

    def __init__(self, dataplane: DataPlane, settings: Settings, commands: Commands, h264: H264Decoder) -> None:
        self.dataplane = dataplane
        self.settings = settings
        self.commands = commands  # INIT (RTP too: its results sent here), WATCH, the state commands
        self.decoding = FrameDecoding(settings, h264)

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
        if self.dataplane.draining:
            why = "this replica is draining: connect again through the Service"
            return await self._refuse(send, error_body(why, DRAINING_REASON, retry_after_s=1), CLOSE_TRY_AGAIN)
        wire = FramesWire(send, self.dataplane.overflowed)
        forwarded = header(scope, FORWARDED_HEADER.lower().encode()) is not None
        connection = Connection(
            wire.key, FRAMES_TRANSPORT, self, wire, granted, token, host, forwarded, wire.watcher, outlives_session=True
        )
        connection.client = (scope.get("client") or ("", 0))[0]
        connection.on_close(wire.stop)
        self.dataplane.connect(connection)
        wire.start()
        try:
            while True:
                message = await receive()
                if message["type"] != "websocket.receive":
                    break  # websocket.disconnect
                data = message.get("bytes")
                if data is not None:
                    await self.on_frame(connection, data)
                else:
                    await self.on_text(connection, message.get("text") or "")
                if len(wire.unsent) >= LOW_WATER:  # the robot does not read its answers: read no more of it
                    await wire.room()
        finally:
            self.dataplane.disconnect(connection, "the robot disconnected")

    async def _refuse(self, send: Any, body: dict[str, Any], code: int) -> None:
        await send({"type": "websocket.send", "text": event(REFUSED_EVENT, body)})
        await send({"type": "websocket.close", "code": code, "reason": body["reason"]})

    @property
    def connections(self) -> list[Connection]:
        """Its robots' open connections."""
        return self.dataplane.connections(FRAMES_TRANSPORT)

    def move_all(self, notice: dict[str, Any]) -> None:
        """A draining replica: every robot here is told to reconnect through the Service."""
        for connection in self.connections:
            connection.wire.tell(event(MOVE_EVENT, notice))

    # -- commands -------------------------------------------------------------------------------------------------

    async def on_text(self, connection: Connection, text: str) -> None:
        wire: FramesWire = connection.wire
        try:
            command = parse_text(text, self.settings.transport_limit_bytes)
        except WireError as exc:
            self.dataplane.refuse(FRAMES_TRANSPORT, exc.reason)
            wire.tell(event(ERROR_EVENT, error_event(None, str(exc), exc.reason)))
            return
        answer = await self.commands.execute(connection, command)
        if answer.session_info is not None:  # what the robot needs before its first frame
            wire.tell(event(SESSION_INFO_EVENT, answer.session_info))
        ack = {"id": command.get("id"), "ok": answer.ok, "message": answer.message, "session_id": connection.key}
        rtp = {RTP_FIELD: answer.rtp} if answer.rtp is not None else {}
        wire.tell(event(ACK_EVENT, **{**ack, **answer.refused, **rtp}))  # a refusal's own fields win, as ever

    # -- frames ---------------------------------------------------------------------------------------------------

    async def on_frame(self, connection: Connection, data: bytes) -> None:
        recv_ns = time.monotonic_ns()
        session = connection.live_session
        label = LABELS.get(data[1] if len(data) > 1 else 0, FRAMES_TRANSPORT)
        timestamp: int | None = None

        async def parse() -> IncomingFrame:
            nonlocal timestamp
            if session is None:
                raise FrameRejected("no_session", "send the INIT command (a text message) before sending frames")
            try:
                frame = parse_frame(data)  # the frames wire's edge
            except WireError as exc:
                raise FrameRejected(exc.reason, str(exc)) from None
            timestamp = frame.timestamp
            return self.decoding.incoming(connection, frame)

        try:
            await self.dataplane.submit(session, label, parse, recv_ns=recv_ns, sink=self)
        except FrameRejected as exc:  # counted by the dataplane
            connection.wire.tell(event(ERROR_EVENT, exc.event(timestamp)))

    # -- the result sink ------------------------------------------------------------------------------------------

    async def result(self, session: Session, message: dict[str, Any]) -> None:
        connection = self.dataplane.connection(session.id)
        if connection is not None:
            connection.wire.tell(event(RESULTS_EVENT, message))

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None:
        connection = self.dataplane.connection(session.id)
        if connection is not None:
            connection.wire.tell(event(ERROR_EVENT, error.event(timestamp)))
