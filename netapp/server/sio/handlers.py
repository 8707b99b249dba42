"""The Socket.IO transport, wire-compatible with 5G-ERA: namespaces /data and /control, INIT with an ack,
frames on `image` (JPEG), results pushed on `results`, errors on `data_error` and `command_error`.

The handlers parse the wire format and call the dataplane (`netapp.server.dataplane`); its errors become error
events and acknowledgements here. The session key is the Engine.IO sid, which both namespaces of one connection
share. The handlers keep each connection's own state (its /data sid, its stream decoders) and close it when the
robot disconnects.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import socketio

from netapp.protocol import (
    COMMAND_ERROR_EVENT,
    COMMAND_EVENT,
    CONTROL_NAMESPACE,
    DATA_ERROR_EVENT,
    DATA_NAMESPACE,
    IMAGE_EVENT,
    RESULTS_EVENT,
    SESSION_INFO_EVENT,
    UNAUTHORIZED_REASON,
    CommandType,
)
from netapp.server import access
from netapp.server.commands import Answer, Commands
from netapp.server.dataplane import DataPlane, IncomingFrame
from netapp.server.decoding.decoder import FrameDecoder
from netapp.server.decoding.jpeg import JpegDecoder
from netapp.server.errors import FrameError, FrameRejected
from netapp.server.rtp.hub import RtpSessions, asks_rtp
from netapp.server.rtp.request import RTP_FIELD
from netapp.server.sessions import Session
from netapp.server.sio.messages import validate_frame_message
from netapp.server.sources.hub import Sources, watch_answer
from netapp.tracecontext import TRACEPARENT, TRACESTATE

log = logging.getLogger(__name__)

TRANSPORT = "ws"  # the `transport` label of JPEG frames and of commands
MAX_WATCH_SENDING = 64  # a watcher's results on their way to it (as `frames`' MAX_UNSENT)
OpenDecoder = Callable[[], FrameDecoder]  # a new connection's decoder for one frame event


@dataclass
class Connection:
    """One robot's Socket.IO connection, keyed by its Engine.IO sid (the session id too, after INIT)."""

    data_sid: str | None = None  # its sid in the /data namespace, where results and data errors go
    decoders: dict[str, FrameDecoder] = field(default_factory=dict)  # by frame event, opened on its first frame
    granted: int | None = None  # the highest priority class its token grants (checked when /control connected)
    watcher: Callable[[dict[str, Any]], None] | None = None  # its subscription to cameras (WATCH), made on the first
    host: str = "127.0.0.1"  # the address it reached us at: where its RTP goes, if it asks for RTP
    token: str | None = None  # what /control connected with: a WATCH relayed from another replica shows it there


class SocketIOHandlers:
    """The handlers of both namespaces; the result sink (`pipeline.frame.ResultSink`) of the frames they
    receive."""

    def __init__(
        self,
        sio: socketio.AsyncServer,
        dataplane: DataPlane,
        sources: Sources | None = None,
        rtp: RtpSessions | None = None,
    ) -> None:
        self.sio = sio
        self.dataplane = dataplane
        self.sources = sources  # the cameras it pulls, whose results a connection may WATCH
        self.rtp = rtp  # sessions whose H.264 comes over RTP (INIT's `rtp`; the answer in `session_info`)
        self.settings = dataplane.settings
        self.connections: dict[str, Connection] = {}  # by Engine.IO sid
        self.commands = Commands(dataplane, TRANSPORT)
        sio.on("connect", self.on_data_connect, namespace=DATA_NAMESPACE)
        sio.on("connect", self.on_control_connect, namespace=CONTROL_NAMESPACE)
        sio.on("disconnect", self.on_data_disconnect, namespace=DATA_NAMESPACE)
        sio.on("disconnect", self.on_control_disconnect, namespace=CONTROL_NAMESPACE)
        sio.on(COMMAND_EVENT, self.on_command, namespace=CONTROL_NAMESPACE)
        jpeg = JpegDecoder(self.settings.max_pixels)
        self.add_frame_event(IMAGE_EVENT, TRANSPORT, lambda: jpeg)

    def add_frame_event(self, event: str, transport: str, open_decoder: OpenDecoder) -> None:
        """Accept frames on `event`, counted under `transport`; each connection's frames go through its own
        decoder from `open_decoder` (JPEG, H.264, ...)."""

        async def handler(sid: str, *args: Any) -> None:
            if len(args) != 1:  # python-socketio passes what the robot sent: never let a wrong arity go silent
                self.dataplane.refuse(transport, "malformed")
                error = f"'{event}' takes one argument (the frame message), got {len(args)}"
                await self.emit_error(sid, None, FrameRejected("malformed", error))
                return
            await self.on_frame(sid, args[0], event, transport, open_decoder)

        self.sio.on(event, handler, namespace=DATA_NAMESPACE)

    def eio_sid(self, sid: str, namespace: str) -> str:
        return self.sio.manager.eio_sid_from_sid(sid, namespace) or sid

    def check_token(self, environ: dict, auth: Any) -> int:
        """Refuse the connection without this netapp's token (when it has one: netapp.server.access); the highest
        priority class its token grants."""
        granted = access.granted_class(self.settings, access.socketio_token(environ, auth))
        if granted is None:
            raise socketio.exceptions.ConnectionRefusedError(
                "this netapp needs a token: connect with auth={'token': ...} (the middleware gives it with the URL)",
                {"reason": UNAUTHORIZED_REASON},  # the connect_error's `data`, for a program
            )
        return granted

    async def on_data_connect(self, sid: str, environ: dict, auth: Any = None) -> None:
        self.check_token(environ, auth)
        self.connections.setdefault(self.eio_sid(sid, DATA_NAMESPACE), Connection()).data_sid = sid
        await self.sio.emit("message", {"message": "connected to /data"}, to=sid, namespace=DATA_NAMESPACE)

    async def on_control_connect(self, sid: str, environ: dict, auth: Any = None) -> None:
        granted = self.check_token(environ, auth)
        connection = self.connections.setdefault(self.eio_sid(sid, CONTROL_NAMESPACE), Connection())
        connection.granted = granted
        connection.token = access.socketio_token(environ, auth)
        connection.host = ((environ.get("asgi.scope") or {}).get("server") or (connection.host,))[0]
        await self.sio.emit("message", {"message": "connected to /control"}, to=sid, namespace=CONTROL_NAMESPACE)

    async def on_data_disconnect(self, sid: str, *reason: Any) -> None:
        self.close(self.eio_sid(sid, DATA_NAMESPACE))

    async def on_control_disconnect(self, sid: str, *reason: Any) -> None:
        self.close(self.eio_sid(sid, CONTROL_NAMESPACE))

    def close(self, eio: str) -> None:
        """The robot went away (either namespace): close its decoders and its session."""
        connection = self.connections.pop(eio, None)
        if connection is not None and connection.watcher is not None and self.sources is not None:
            self.sources.unsubscribe(connection.watcher)
        if connection is not None:
            for decoder in connection.decoders.values():
                decoder.close()
        session = self.dataplane.services.sessions.get(eio)
        if session is not None:
            self.dataplane.close_session(session, "the robot disconnected")

    # -- /control ---------------------------------------------------------------------------------------------------

    async def on_command(self, sid: str, *args: Any) -> tuple[bool, str]:
        eio = self.eio_sid(sid, CONTROL_NAMESPACE)
        refused: dict[str, Any] = {}
        rtp: dict[str, Any] | None = None
        if len(args) != 1:
            ok, message = False, f"'{COMMAND_EVENT}' takes one argument (the command), got {len(args)}"
        elif self.rtp is not None and asks_rtp(args[0]):
            host = self.connections.get(eio, Connection()).host
            ok, message, refused, rtp = await self.rtp.init(
                eio, args[0], lambda: self._execute(eio, args[0]), self, host
            )
        else:
            ok, message, refused = await self._execute(eio, args[0])
        if ok and isinstance(args[0], dict) and args[0].get("cmd_type") == CommandType.INIT:
            # Before the ack, as command_error is: the ack keeps 5G-ERA's (ok, message), which an unmodified
            # era-5g-client unpacks, and an event it has no handler for is ignored by it.
            info = self.dataplane.session_info()
            if rtp is not None:  # the port, SSRC and SDP of an RTP session (docs/cameras.md#rtp-push)
                info = {**info, RTP_FIELD: rtp}
            await self.sio.emit(SESSION_INFO_EVENT, info, to=sid, namespace=CONTROL_NAMESPACE)
        if not ok:
            self.dataplane.refuse(TRANSPORT, "bad_command")
            # Before the ack, so a client handling messages in order knows why when the ack comes. The ack keeps
            # 5G-ERA's (ok, message), which the unmodified era-5g-client unpacks; its command_error callback gets
            # this mapping and ignores the keys it does not know.
            error = {"error": message, **refused}
            await self.sio.emit(COMMAND_ERROR_EVENT, error, to=sid, namespace=CONTROL_NAMESPACE)
        return ok, message

    async def execute(self, eio: str, command: Any) -> tuple[bool, str]:
        """Apply one control command; (ok, message) is the 5G-ERA acknowledgement."""
        ok, message, _ = await self._execute(eio, command)
        return ok, message

    async def _execute(self, eio: str, command: Any) -> Answer:
        """(ok, message, the machine-readable part of a refusal: `reason`, `retry_after_s`, details)."""
        connection = self.connections.get(eio)
        if isinstance(command, dict) and command.get("cmd_type") == CommandType.WATCH:
            return self._watch(eio, command)
        if connection is None:
            return await self.commands.execute(eio, command)
        decoders = list(connection.decoders.values())
        return await self.commands.execute(eio, command, granted=connection.granted, decoders=decoders)

    def _watch(self, eio: str, command: dict[str, Any]) -> Answer:
        """WATCH: this connection's /data gets the results of the camera `data.source` (docs/cameras.md#results)."""
        connection = self.connections.setdefault(eio, Connection())
        if connection.watcher is None:
            connection.watcher = self._watcher(eio)
        return watch_answer(self.sources, command, connection.watcher, connection.token)

    def _watcher(self, eio: str) -> Callable[[dict[str, Any]], None]:
        """A connection's subscriber: each result emitted on its /data without waiting, at most MAX_WATCH_SENDING
        on their way (past it, for a robot that does not read, they are dropped and counted)."""
        sending: set[asyncio.Task] = set()
        overflowed = self.dataplane.services.metrics.results_overflowed

        def tell(message: dict[str, Any]) -> None:
            sid = self._data_sid(eio)
            if sid is None:
                return
            if len(sending) >= MAX_WATCH_SENDING:
                overflowed.inc()
                return
            task = asyncio.ensure_future(self.sio.emit(RESULTS_EVENT, message, to=sid, namespace=DATA_NAMESPACE))
            sending.add(task)
            task.add_done_callback(sending.discard)

        return tell

    # -- /data ------------------------------------------------------------------------------------------------------

    async def result(self, session: Session, message: dict[str, Any]) -> None:
        sid = self._data_sid(session.id)
        if sid is not None:
            await self.sio.emit(RESULTS_EVENT, message, to=sid, namespace=DATA_NAMESPACE)

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None:
        sid = self._data_sid(session.id)
        if sid is not None:
            await self.emit_error(sid, timestamp, error)

    def _data_sid(self, eio: str) -> str | None:
        connection = self.connections.get(eio)
        return connection.data_sid if connection is not None else None

    async def emit_error(self, sid: str, timestamp: int | None, error: FrameError) -> None:
        # `reason` (beyond 5G-ERA's two keys) lets a client act, e.g. restart its H.264 stream with a keyframe.
        await self.sio.emit(DATA_ERROR_EVENT, error.event(timestamp), to=sid, namespace=DATA_NAMESPACE)

    async def on_frame(self, sid: str, message: Any, event: str, transport: str, open_decoder: OpenDecoder) -> None:
        recv_ns = time.monotonic_ns()
        eio = self.eio_sid(sid, DATA_NAMESPACE)
        timestamp = message.get("timestamp") if isinstance(message, dict) else None
        session = self.dataplane.services.sessions.get(eio)

        async def parse() -> IncomingFrame:
            if session is None:
                raise FrameRejected("no_session", "send the INIT command on /control before sending data")
            deadline_ms = validate_frame_message(message, self.settings.max_payload_bytes)
            decoder = self._decoder(eio, event, open_decoder)
            decode = decoder.frame(message)
            metadata = message.get("metadata")
            metadata = metadata if isinstance(metadata, dict) else {}
            size = len(message.get("frame") or b"")  # bounded by `validate_frame_message`
            return IncomingFrame(
                timestamp,
                decode,
                deadline_ms,
                robot_latency=metadata.get("latency"),
                size_bytes=size,
                in_order=decoder.in_order,
                traceparent=metadata.get(TRACEPARENT),
                tracestate=metadata.get(TRACESTATE),
            )

        try:
            await self.dataplane.submit(session, transport, parse, recv_ns=recv_ns, sink=self)
        except FrameRejected as exc:  # counted by the dataplane
            await self.emit_error(sid, timestamp, exc)

    def _decoder(self, eio: str, event: str, open_decoder: OpenDecoder) -> FrameDecoder:
        """The connection's decoder for `event`, per (connection, event) as in 5G-ERA."""
        connection = self.connections.setdefault(eio, Connection())
        decoder = connection.decoders.get(event)
        if decoder is None:
            decoder = connection.decoders[event] = open_decoder()
        return decoder
