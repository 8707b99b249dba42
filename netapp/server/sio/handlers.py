"""The Socket.IO transport, wire-compatible with 5G-ERA: namespaces /data and /control, INIT with an ack,
frames on `image` (JPEG), results pushed on `results`, errors on `data_error` and `command_error`.

The handlers convert the wire format at its edge (a frame message to an `EncodedFrame`, `sio.messages`) and call
the dataplane (`netapp.server.dataplane`) and the one command dispatch (`netapp.server.commands`); their errors
become error events and acknowledgements here. Each robot's connection is one `Connection` (`netapp.server.connection`)
keyed by its Engine.IO sid, which both namespaces of one connection share (the session id too, after INIT); its wire's
own part is its /data sid. It is closed (`DataPlane.disconnect`) when the robot disconnects from either namespace.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

import socketio

from netapp.frame import JPEG
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
)
from netapp.server import access
from netapp.server.commands import Commands
from netapp.server.connection import Connection
from netapp.server.dataplane import DataPlane, IncomingFrame
from netapp.server.decoding.decoder import FrameDecoder
from netapp.server.decoding.jpeg import JpegDecoder
from netapp.server.errors import FrameError, FrameRejected
from netapp.server.rtp.request import RTP_FIELD
from netapp.server.sessions import Session
from netapp.server.settings import Settings
from netapp.server.sio.messages import frame_from_message

log = logging.getLogger(__name__)

TRANSPORT = "ws"  # the `transport` label of JPEG frames and of commands
MAX_WATCH_SENDING = 64  # a watcher's results on their way to it (as `frames`' MAX_UNSENT)
OpenDecoder = Callable[[], FrameDecoder]  # a new connection's decoder for one frame event


class SocketIOHandlers:
    """The handlers of both namespaces; the result sink (`pipeline.frame.ResultSink`) of the frames they
    receive."""

    def __init__(self, sio: socketio.AsyncServer, dataplane: DataPlane, settings: Settings, commands: Commands) -> None:
        self.sio = sio
        self.dataplane = dataplane
        self.settings = settings
        self.commands = commands  # INIT (RTP too: the answer in `session_info`), WATCH, the state commands
        sio.on("connect", self.on_data_connect, namespace=DATA_NAMESPACE)
        sio.on("connect", self.on_control_connect, namespace=CONTROL_NAMESPACE)
        sio.on("disconnect", self.on_data_disconnect, namespace=DATA_NAMESPACE)
        sio.on("disconnect", self.on_control_disconnect, namespace=CONTROL_NAMESPACE)
        sio.on(COMMAND_EVENT, self.on_command, namespace=CONTROL_NAMESPACE)
        jpeg = JpegDecoder(self.settings.max_pixels)
        self.add_frame_event(IMAGE_EVENT, TRANSPORT, JPEG, lambda: jpeg)

    def add_frame_event(self, event: str, transport: str, codec: str, open_decoder: OpenDecoder) -> None:
        """Accept frames of `codec` on `event`, counted under `transport`; each connection's frames go through its
        own decoder from `open_decoder` (JPEG, H.264, ...)."""

        async def handler(sid: str, *args: Any) -> None:
            if len(args) != 1:  # python-socketio passes what the robot sent: never let a wrong arity go silent
                self.dataplane.refuse(transport, "malformed")
                error = f"'{event}' takes one argument (the frame message), got {len(args)}"
                await self.emit_error(sid, None, FrameRejected("malformed", error))
                return
            await self.on_frame(sid, args[0], event, transport, codec, open_decoder)

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

    def connection(self, eio: str) -> Connection:
        """The robot's connection (made by whichever namespace it reaches first)."""
        connection = self.dataplane.connection(eio)
        if connection is None:
            connection = Connection(eio, TRANSPORT, self, tell=self._watcher(eio), outlives_session=True)
            self.dataplane.connect(connection)
        return connection

    async def on_data_connect(self, sid: str, environ: dict, auth: Any = None) -> None:
        self.check_token(environ, auth)
        self.connection(self.eio_sid(sid, DATA_NAMESPACE)).wire = sid  # where its results and data errors go
        await self.sio.emit("message", {"message": "connected to /data"}, to=sid, namespace=DATA_NAMESPACE)

    async def on_control_connect(self, sid: str, environ: dict, auth: Any = None) -> None:
        granted = self.check_token(environ, auth)
        connection = self.connection(self.eio_sid(sid, CONTROL_NAMESPACE))
        connection.granted = granted
        connection.token = access.socketio_token(environ, auth)
        connection.host = ((environ.get("asgi.scope") or {}).get("server") or (connection.host,))[0]
        connection.client = ((environ.get("asgi.scope") or {}).get("client") or ("",))[0]
        await self.sio.emit("message", {"message": "connected to /control"}, to=sid, namespace=CONTROL_NAMESPACE)

    async def on_data_disconnect(self, sid: str, *reason: Any) -> None:
        self.close(self.eio_sid(sid, DATA_NAMESPACE))

    async def on_control_disconnect(self, sid: str, *reason: Any) -> None:
        self.close(self.eio_sid(sid, CONTROL_NAMESPACE))

    def close(self, eio: str) -> None:
        """The robot went away (either namespace): its connection closes (its session, decoders, subscriptions)."""
        connection = self.dataplane.connection(eio)
        if connection is not None:
            self.dataplane.disconnect(connection, "the robot disconnected")

    # -- /control ---------------------------------------------------------------------------------------------------

    async def on_command(self, sid: str, *args: Any) -> tuple[bool, str]:
        connection = self.connection(self.eio_sid(sid, CONTROL_NAMESPACE))
        if len(args) != 1:
            self.dataplane.refuse(TRANSPORT, "bad_command")
            message = f"'{COMMAND_EVENT}' takes one argument (the command), got {len(args)}"
            await self.sio.emit(COMMAND_ERROR_EVENT, {"error": message}, to=sid, namespace=CONTROL_NAMESPACE)
            return False, message
        answer = await self.commands.execute(connection, args[0])
        if answer.session_info is not None:
            # Before the ack, as command_error is: the ack keeps 5G-ERA's (ok, message), which an unmodified
            # era-5g-client unpacks, and an event it has no handler for is ignored by it. With RTP, the port, SSRC
            # and SDP of its session are in it (docs/cameras.md#rtp-push).
            info = answer.session_info if answer.rtp is None else {**answer.session_info, RTP_FIELD: answer.rtp}
            await self.sio.emit(SESSION_INFO_EVENT, info, to=sid, namespace=CONTROL_NAMESPACE)
        if not answer.ok:
            # Before the ack, so a client handling messages in order knows why when the ack comes. The ack keeps
            # 5G-ERA's (ok, message), which the unmodified era-5g-client unpacks; its command_error callback gets
            # this mapping and ignores the keys it does not know.
            error = {"error": answer.message, **answer.refused}
            await self.sio.emit(COMMAND_ERROR_EVENT, error, to=sid, namespace=CONTROL_NAMESPACE)
        return answer.ok, answer.message

    def _watcher(self, eio: str) -> Callable[[dict[str, Any]], bool]:
        """A connection's subscriber: each result emitted on its /data without waiting, at most MAX_WATCH_SENDING
        on their way (past it, for a robot that does not read, they are dropped, counted, and it says False)."""
        sending: set[asyncio.Task] = set()

        def tell(message: dict[str, Any]) -> bool:
            sid = self._data_sid(eio)
            if sid is None:
                return False
            if len(sending) >= MAX_WATCH_SENDING:
                self.dataplane.overflowed()
                return False
            task = asyncio.ensure_future(self.sio.emit(RESULTS_EVENT, message, to=sid, namespace=DATA_NAMESPACE))
            sending.add(task)
            task.add_done_callback(sending.discard)
            return True

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
        connection = self.dataplane.connection(eio)
        return connection.wire if connection is not None else None

    async def emit_error(self, sid: str, timestamp: int | None, error: FrameError) -> None:
        # `reason` (beyond 5G-ERA's two keys) lets a client act, e.g. restart its H.264 stream with a keyframe.
        await self.sio.emit(DATA_ERROR_EVENT, error.event(timestamp), to=sid, namespace=DATA_NAMESPACE)

    async def on_frame(
        self, sid: str, message: Any, event: str, transport: str, codec: str, open_decoder: OpenDecoder
    ) -> None:
        recv_ns = time.monotonic_ns()
        connection = self.dataplane.connection(self.eio_sid(sid, DATA_NAMESPACE))  # gone: a frame after disconnect
        timestamp = message.get("timestamp") if isinstance(message, dict) else None
        session = connection.live_session if connection is not None else None

        async def parse() -> IncomingFrame:
            if connection is None or session is None:
                raise FrameRejected("no_session", "send the INIT command on /control before sending data")
            frame = frame_from_message(message, codec, self.settings.max_payload_bytes)  # Socket.IO's edge
            decoder = connection.decoder(event, open_decoder)  # per (connection, event), as in 5G-ERA
            return IncomingFrame(frame, decoder.frame(frame), in_order=decoder.in_order)

        try:
            await self.dataplane.submit(session, transport, parse, recv_ns=recv_ns, sink=self)
        except FrameRejected as exc:  # counted by the dataplane
            await self.emit_error(sid, timestamp, exc)
