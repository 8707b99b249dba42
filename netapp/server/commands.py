"""The 5G-ERA control commands (INIT, RESET_STATE and the state commands), whatever the transport that carries them.

A command is `{"cmd_type": int, "clear_queue": bool, "data": {...}}`; its answer is 5G-ERA's acknowledgement
(ok, message), plus the machine-readable part of a refusal (`reason`, `retry_after_s`, ...). The Socket.IO handlers
(`netapp.server.sio.handlers`) and the frames endpoint (`netapp.server.frames.endpoint`) parse their wire format and
call `execute`; the work is the dataplane's.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from typing import Any

from netapp.protocol import CommandType
from netapp.server.dataplane import DataPlane
from netapp.server.decoding.decoder import FrameDecoder
from netapp.server.errors import ServingError, refusal_fields
from netapp.server.sessions import Session

Answer = tuple[bool, str, dict[str, Any]]  # (ok, message, the refusal's fields)


class Commands:
    """Runs control commands for one transport's connections over `dataplane`."""

    def __init__(self, dataplane: DataPlane, transport: str) -> None:
        self.dataplane = dataplane
        self.transport = transport  # the label of the sessions INIT opens

    async def execute(
        self, key: str, command: Any, *, granted: int | None = None, decoders: Iterable[FrameDecoder] = ()
    ) -> Answer:
        """Apply one command of the connection whose session is (or becomes, at INIT) `key`; `granted` is the
        priority class its token grants, `decoders` its stream decoders (RESET_STATE resets them)."""
        if not isinstance(command, dict) or "cmd_type" not in command:
            return False, "malformed command: expected {'cmd_type': int, 'clear_queue': bool, 'data': {...}}", {}
        try:
            cmd_type = CommandType(command["cmd_type"])
        except (ValueError, TypeError):
            return False, f"unknown cmd_type {command.get('cmd_type')!r}", {}
        data = command.get("data") or {}
        if not isinstance(data, dict):
            return False, "command data must be a mapping", {}
        try:
            ok, message = await self._apply(key, cmd_type, command, data, granted, decoders)
        except ServingError as exc:
            return False, str(exc), refusal_fields(exc)
        return ok, message, {}

    async def _apply(
        self,
        key: str,
        cmd_type: CommandType,
        command: dict,
        data: dict[str, Any],
        granted: int | None,
        decoders: Iterable[FrameDecoder],
    ) -> tuple[bool, str]:
        dataplane = self.dataplane
        session = dataplane.services.sessions.get(key)
        if cmd_type is CommandType.INIT:
            if session is not None:
                return False, "this session is already initialized (a second INIT is refused)"
            dataplane.open_session(self.transport, data.get("robot_id"), data, session_id=key, granted=granted)
            return True, "initialized"
        if session is None:
            return False, "send the INIT command first"
        if command.get("clear_queue"):
            dataplane.clear_queue(session, "queue cleared by a command")
        if cmd_type is CommandType.RESET_STATE:
            for decoder in decoders:
                decoder.reset()
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
