"""The one command dispatch: INIT (with or without RTP), WATCH and the state commands, whatever the transport that
carries them, and HTTP's `POST /register`, which opens a session as INIT does.

A command is `{"cmd_type": int, "clear_queue": bool, "data": {...}}`; its answer is 5G-ERA's acknowledgement
(ok, message), plus the machine-readable part of a refusal (`reason`, `retry_after_s`, ...), and what INIT tells the
robot beside it (`session_info`, with an RTP session's port). The Socket.IO handlers (`netapp.server.sio.handlers`)
and the frames endpoint (`netapp.server.frames.endpoint`) parse their wire format and call `execute` with their
`Connection`; the HTTP route calls `register`. The work is the dataplane's.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from netapp.protocol import CommandType
from netapp.server.connection import Connection
from netapp.server.dataplane import DataPlane
from netapp.server.errors import ServingError, refusal_fields
from netapp.server.rtp.hub import PollingSink, RtpSessions
from netapp.server.rtp.request import RTP_FIELD, RtpRequest
from netapp.server.sessions import TOKEN_TRANSPORT, Session
from netapp.server.sources.hub import Sources, watch_answer

MALFORMED = "malformed command: expected {'cmd_type': int, 'clear_queue': bool, 'data': {...}}"


@dataclass(frozen=True)
class Answer:
    """What a command comes to: 5G-ERA's (ok, message), a refusal's fields, and after an INIT what the robot learns
    with its acknowledgement (`session_info`: its processor's `input_size`; with RTP, `rtp`: the port, SSRC and SDP
    to send to)."""

    ok: bool
    message: str
    refused: dict[str, Any] = field(default_factory=dict)
    session_info: dict[str, Any] | None = None
    rtp: dict[str, Any] | None = None


@dataclass(frozen=True)
class Registered:
    """`POST /register`'s session and, when it asked for RTP, where to send its H.264."""

    session: Session
    rtp: dict[str, Any] | None


class Commands:
    """Runs every connection's control commands over `dataplane`, with the app's cameras (`sources`, for WATCH) and
    RTP sessions (`rtp`, for an INIT or `/register` with `rtp`)."""

    def __init__(self, dataplane: DataPlane, sources: Sources | None = None, rtp: RtpSessions | None = None) -> None:
        self.dataplane = dataplane
        self.sources = sources
        self.rtp = rtp

    async def execute(self, connection: Connection, command: Any) -> Answer:
        """Apply one command of `connection`; a refused one is counted (`bad_command`)."""
        answer = await self._answer(connection, command)
        if not answer.ok:
            self.dataplane.refuse(connection.transport, "bad_command")
        return answer

    async def register(self, robot_id: str | None, args: dict[str, Any], granted: int, host: str) -> Registered:
        """`POST /register`: a token session (`DataPlane.register`), opened as INIT opens one, RTP included, its
        results kept for polling; ServingError when it cannot be."""
        connection = Connection("", TOKEN_TRANSPORT, PollingSink(self.dataplane), granted=granted, host=host)
        request = self._rtp_request(args)  # before any session opens
        session = self.dataplane.register(robot_id, args, granted, connection)
        return Registered(session, await self._open_rtp(connection, request, revoke=True))

    async def _answer(self, connection: Connection, command: Any) -> Answer:
        if not isinstance(command, dict) or "cmd_type" not in command:
            return Answer(False, MALFORMED)
        try:
            cmd_type = CommandType(command["cmd_type"])
        except (ValueError, TypeError):
            return Answer(False, f"unknown cmd_type {command.get('cmd_type')!r}")
        if cmd_type is CommandType.WATCH:
            return self._watch(connection, command)
        data = command.get("data") or {}
        if not isinstance(data, dict):
            return Answer(False, "command data must be a mapping")
        try:
            if cmd_type is CommandType.INIT:
                return await self._init(connection, data)
            ok, message = await self._apply(connection, cmd_type, command, data)
        except ServingError as exc:
            return Answer(False, str(exc), refusal_fields(exc))
        return Answer(ok, message)

    def _rtp_request(self, args: dict[str, Any]) -> RtpRequest | None:
        """A session's `rtp` argument, checked before its session opens (None: it asks for none)."""
        return self.rtp.check(args[RTP_FIELD]) if self.rtp is not None and RTP_FIELD in args else None

    async def _open_rtp(self, connection: Connection, request: RtpRequest | None, revoke: bool) -> dict | None:
        """Its RTP port, held by its connection; where none is free, its session is closed again."""
        session = connection.session
        if request is None or self.rtp is None or session is None:
            return None
        try:
            return await self.rtp.open(connection, request)
        except ServingError as exc:
            self.dataplane.close_session(session, str(exc), revoke=revoke)
            raise

    async def _init(self, connection: Connection, data: dict[str, Any]) -> Answer:
        request = self._rtp_request(data)
        if connection.live_session is not None:
            return Answer(False, "this session is already initialized (a second INIT is refused)")
        dataplane = self.dataplane
        dataplane.open_session(
            connection.transport,
            data.get("robot_id"),
            data,
            session_id=connection.key,
            granted=connection.granted,
            connection=connection,
        )
        rtp = await self._open_rtp(connection, request, revoke=False)
        message = "initialized" if rtp is None else f"initialized; send H.264 over RTP to port {rtp['port']}"
        return Answer(True, message, session_info=dataplane.session_info(), rtp=rtp)

    def _watch(self, connection: Connection, command: dict[str, Any]) -> Answer:
        """WATCH: the connection gets the results of the camera `data.source` (docs/cameras.md#results)."""
        tell = connection.tell
        if tell is None:
            return Answer(False, "this connection cannot watch a camera", {"reason": "no_sources"})
        ok, message, refused = watch_answer(
            self.sources, command, tell, connection.token, connection.forwarded, connection.client
        )
        if ok and self.sources is not None:
            unsubscribe: Callable[[], None] = lambda sources=self.sources: sources.unsubscribe(tell)  # noqa: E731
            connection.on_close(unsubscribe)
        return Answer(ok, message, refused)

    async def _apply(
        self, connection: Connection, cmd_type: CommandType, command: dict, data: dict[str, Any]
    ) -> tuple[bool, str]:
        dataplane = self.dataplane
        session = connection.live_session
        if session is None:
            return False, "send the INIT command first"
        if command.get("clear_queue"):
            dataplane.clear_queue(session, "queue cleared by a command")
        if cmd_type is CommandType.RESET_STATE:
            connection.reset_decoders()
            await dataplane.reset_state(session)
            return True, "state reset"
        if session.state is None:  # a stateless processor: GET_STATE tells the session's counters
            if cmd_type is CommandType.GET_STATE:
                return True, json.dumps(dataplane.stats(session))
            return False, f"command {cmd_type.name} needs a stateful processor; this netapp's keeps no state"
        return await self.state_command(session, cmd_type, data)

    async def state_command(self, session: Session, cmd_type: CommandType, data: dict[str, Any]) -> tuple[bool, str]:
        """GET_STATE (the ack's message is the state as JSON text), SET_STATE (`data` is that state), SAVE_STATE
        and LOAD_STATE (`data.name`, else the robot id, names it in the --state-dir volume)."""
        dataplane = self.dataplane
        if cmd_type is CommandType.GET_STATE:
            return True, await dataplane.get_state(session)
        if cmd_type is CommandType.SET_STATE:
            await dataplane.set_state(session, data)
            return True, "state set"
        name = data.get("name") or session.robot_id
        if not name:
            return False, f"{cmd_type.name} needs data {{'name': ...}} (or a robot_id in INIT) to name the state"
        if cmd_type is CommandType.SAVE_STATE:
            await dataplane.save_state(session, name)
            return True, f"state saved as {name!r}"
        await dataplane.load_state(session, name)
        return True, f"state {name!r} loaded"
