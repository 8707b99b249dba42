"""What one broker's frames channel offers, on either end (`netapp.broker.channels`): a frame taken from the work
queue (`Incoming`), settled once it is answered, and the calls each end makes."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Protocol

from netapp.broker.frames import Envelope


@dataclass
class Incoming:
    """One frame message from the work queue. `envelope` is None when its headers were not a robot's (`problem`
    says why); `ack` once it is answered (or superseded, or stale), `reject` to dead-letter it (poison: never
    redelivered)."""

    body: bytes
    envelope: Envelope | None
    problem: str | None
    correlation: str | None
    ack: Callable[[], Awaitable[None]]
    reject: Callable[[], Awaitable[None]]


class FrameChannel(Protocol):
    # whether one robot's frames may go to any replica on the queue (then no replica can promise the robot a turn)
    spreads_robots: bool

    async def connect(self) -> None: ...

    async def consume(self, handler: Callable[[Incoming], Awaitable[None]]) -> None:
        """The netapp's end: `handler` gets each frame message, at most `prefetch` unsettled at once."""
        ...

    async def reply(self, envelope: Envelope, correlation: str | None, body: bytes) -> None:
        """The netapp's end: a frames text event to the reply address of the robot `envelope` names."""
        ...

    async def open_replies(self, session: str, handler: Callable[[bytes], Awaitable[None]]) -> str:
        """The robot's end: start reading its replies; the reply address its frames name."""
        ...

    async def send(self, body: bytes, envelope: Envelope, correlation: str, deadline_ms: float | None) -> None:
        """The robot's end: one frame message to the work queue."""
        ...

    async def wait_closed(self) -> None:
        """Returns once the connection is lost (or closed)."""
        ...

    async def close(self) -> None: ...
