"""The wire's own part of one robot's `frames` WebSocket (its `Connection`'s `wire`, `netapp.server.connection`): what
it is sent goes out by its own writer task.

The pipeline hands results to the endpoint (its result sink) in line, one after another for every robot; a robot
that stops reading must never hold that up. So `tell` never waits: it queues the message, and the connection's writer
task waits on the robot's socket instead (uvicorn makes a send wait while the transport's buffer is over its high-water
mark). A robot that reads nothing keeps at most `MAX_UNSENT` messages here (the newer ones are dropped and counted in
`netapp_results_overflowed`, one log line)
until uvicorn's ping timeout closes its connection. What the robot's own messages are answered with (errors, acks)
never overflows: past `LOW_WATER` waiting, the endpoint reads nothing more from that robot until it has read them
(`room`), so a robot that floods is slowed to the pace it reads at, and nobody else is.
"""

from __future__ import annotations

import asyncio
import logging
import uuid
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from netapp.framing import event
from netapp.protocol import RESULTS_EVENT

log = logging.getLogger(__name__)

MAX_UNSENT = 64  # messages waiting for a robot that does not read (a result is about 1 KB)
LOW_WATER = MAX_UNSENT // 2  # past it, the robot's next message waits (`room`)


@dataclass(eq=False)
class FramesWire:
    """One robot's WebSocket, sending; `key` names its connection (its session's id once INIT opened it)."""

    send: Any  # the ASGI send
    dropped: Callable[[], None] = lambda: None  # counts a message dropped because the robot reads nothing
    key: str = field(default_factory=lambda: uuid.uuid4().hex)
    open: bool = True
    unsent: deque[str] = field(default_factory=deque)
    overflowed: bool = False
    _wake: asyncio.Event = field(default_factory=asyncio.Event)
    _drained: asyncio.Event = field(default_factory=asyncio.Event)  # fewer than LOW_WATER wait
    _writer: asyncio.Task | None = None

    def start(self) -> None:
        self._writer = asyncio.ensure_future(self._write())

    def tell(self, text: str) -> bool:
        """Send one text message, without waiting (see the module); whether it was taken (not dropped)."""
        if not self.open:
            return False
        if len(self.unsent) >= MAX_UNSENT:
            self.dropped()
            if not self.overflowed:
                log.warning("frames robot %s reads nothing: messages to it are dropped", self.key)
                self.overflowed = True
            return False
        self.unsent.append(text)
        self._wake.set()
        return True

    def watcher(self, message: dict[str, Any]) -> bool:
        """A result of a camera it WATCHes (`netapp.server.sources.hub`), told like its own; whether it was taken."""
        return self.tell(event(RESULTS_EVENT, message))

    async def room(self) -> None:
        """Return once fewer than LOW_WATER messages wait for the robot (or the connection is closed)."""
        while self.open and len(self.unsent) >= LOW_WATER:
            self._drained.clear()
            await self._drained.wait()

    def stop(self) -> None:
        self.open = False
        self.unsent.clear()
        self._drained.set()
        if self._writer is not None:
            self._writer.cancel()

    async def _write(self) -> None:
        while self.open:
            await self._wake.wait()
            self._wake.clear()
            while self.unsent:
                text = self.unsent.popleft()
                try:
                    await self.send({"type": "websocket.send", "text": text})
                except Exception as exc:  # uvicorn's own (ClientDisconnected), or OSError: the receive loop ends it
                    log.debug("frames connection %s: send failed: %s", self.key, exc)
                    self.open = False
                    self._drained.set()
                    return
                if len(self.unsent) < LOW_WATER:
                    self._drained.set()
            self.overflowed = False
