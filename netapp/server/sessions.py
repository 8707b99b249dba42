"""Robot sessions: a bounded newest-wins frame queue and the place results go."""

from __future__ import annotations

import asyncio
import time
import uuid
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

from netapp.server.errors import FrameRejected

ResultSink = Callable[["Session", dict[str, Any]], Awaitable[None]]
ErrorSink = Callable[["Session", int | None, FrameRejected], Awaitable[None]]


@dataclass
class Frame:
    timestamp: int
    recv_ns: int
    seq: int
    prepared: Any = None
    decode: Callable[[], Any] | None = None  # still to decode and prepare, on the inference thread
    waiter: asyncio.Future | None = None  # HTTP ?wait=true


@dataclass
class Session:
    id: str
    transport: str  # "http", "ws" or "h264": the label of its metrics
    robot_id: str | None
    args: dict[str, Any]
    queue_size: int
    results_buffer: int
    send_result: ResultSink | None = None  # push transports; None: results are kept for polling
    send_error: ErrorSink | None = None
    last_seen: float = field(default_factory=time.monotonic)
    pending: deque[Frame] = field(default_factory=deque)
    results: deque[dict[str, Any]] = field(default_factory=deque)
    received: int = 0
    processed: int = 0
    dropped: int = 0
    rejected: int = 0
    results_overflowed: int = 0
    closed: bool = False
    queued: bool = False  # in the pipeline's ready queue
    next_seq: int = 0
    last_seq: int = -1
    context: dict[str, Any] = field(default_factory=dict)  # per-transport state, e.g. an H.264 decoder
    state: Any = None  # a stateful processor's state (netapp.server.session_state.SessionState)

    def take_seq(self) -> int:
        """Receive order, fixed before concurrent decoding can reorder frames."""
        self.next_seq += 1
        return self.next_seq

    def keep_result(self, result: dict[str, Any]) -> bool:
        """For polling: bounded, so a robot that never polls cannot grow the server's memory. True when the
        oldest kept result had to go (counted)."""
        overflowed = len(self.results) >= self.results_buffer
        if overflowed:
            self.results.popleft()
            self.results_overflowed += 1
        self.results.append(result)
        return overflowed

    def drain_results(self) -> list[dict[str, Any]]:
        out = list(self.results)
        self.results.clear()
        return out

    def stats(self) -> dict[str, Any]:
        return {
            "session_id": self.id,
            "transport": self.transport,
            "robot_id": self.robot_id,
            "received": self.received,
            "processed": self.processed,
            "dropped": self.dropped,
            "rejected": self.rejected,
            "queue_depth": len(self.pending),
        }


class SessionRegistry:
    """All live sessions by id."""

    def __init__(self, queue_size: int, results_buffer: int) -> None:
        self.queue_size = queue_size
        self.results_buffer = results_buffer
        self._sessions: dict[str, Session] = {}

    def create(
        self,
        transport: str,
        robot_id: str | None = None,
        args: dict[str, Any] | None = None,
        session_id: str | None = None,
        **sinks: Any,
    ) -> Session:
        session = Session(
            id=session_id or uuid.uuid4().hex,
            transport=transport,
            robot_id=robot_id,
            args=dict(args or {}),
            queue_size=self.queue_size,
            results_buffer=self.results_buffer,
            **sinks,
        )
        self._sessions[session.id] = session
        return session

    def get(self, session_id: str | None) -> Session | None:
        return self._sessions.get(session_id) if session_id else None

    def remove(self, session_id: str) -> Session | None:
        session = self._sessions.pop(session_id, None)
        if session is not None:
            session.closed = True
        return session

    def idle(self, ttl_s: float, transport: str) -> list[Session]:
        cutoff = time.monotonic() - ttl_s
        return [s for s in self._sessions.values() if s.transport == transport and s.last_seen < cutoff]

    def __iter__(self):
        return iter(list(self._sessions.values()))

    def count(self, transport: str) -> int:
        return sum(1 for s in self._sessions.values() if s.transport == transport)
