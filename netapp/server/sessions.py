"""Robot sessions: who the robot is, what it has sent, and the results it has yet to poll.

What else a session needs has its own owner: the pipeline keeps its frame queue (`netapp.server.pipeline.scheduling`),
its transport's `Connection` its decoders and what its wire holds (`netapp.server.connection`); the dataplane opens and
closes it (`netapp.server.dataplane`).
"""

from __future__ import annotations

import math
import sys
import time
import uuid
from collections import OrderedDict, deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from netapp.protocol import DEFAULT_PRIORITY, NEEDS_FIELD, PRIORITY_CLASSES
from netapp.server.capacity import InputRate, smoothed
from netapp.server.errors import SessionsFull
from netapp.server.retry_after import sessions_retry_after_s


@dataclass
class Session:
    id: str
    transport: str  # how the robot registered: "http", "ws", "frames", "webrtc" or, for a camera, "rtsp"
    robot_id: str | None
    args: dict[str, Any]
    results_buffer: int
    last_seen: float = field(default_factory=time.monotonic)
    opened_s: float = field(default_factory=time.monotonic)
    results: deque[dict[str, Any]] = field(default_factory=deque)  # kept for polling (HTTP without wait)
    received: int = 0
    processed: int = 0
    dropped: int = 0
    deadline_dropped: int = 0  # dropped before inference: it could not meet the robot's deadline
    rejected: int = 0
    results_overflowed: int = 0
    closed: bool = False
    streams: str | None = None  # the transport of its latest frame, e.g. "h264" for Socket.IO with H.264
    rate: InputRate = field(default_factory=InputRate)  # its input rate, for the capacity estimate
    # a stateful processor's state (`netapp.server.pipeline.state_keeper`): read and changed on the inference
    # thread only
    state: Any = None
    # admitted here (INIT, /register), so counted against the cap; False: a record of an HTTP token another replica
    # admitted (that one counts it), or of one whose record here had expired
    admitted: bool = True
    # what one of its frames costs the inference thread, seconds (a moving average; 0: not yet measured): its turns
    # are weighed by it (`netapp.server.pipeline.scheduling`)
    cost_s: float = 0.0
    priority: int = PRIORITY_CLASSES.index(
        DEFAULT_PRIORITY
    )  # its priority class (an index of `netapp.protocol.PRIORITY_CLASSES`), set when it opens
    owner_asked_s: float = -math.inf  # when its token's owner was last asked whether it was revoked (cluster)
    waiting: int = 0  # its `?wait=true` requests waiting for their result (capped: Settings.max_waiting_per_session)
    # what its robot sends now, as seen here (the pages show it: a robot whose uplink adapts changes both)
    frame_bytes: float = 0.0  # bytes per frame, a moving average over the last few frames
    frame_size: tuple[int, int] | None = None  # (width, height) of its latest decoded frame
    # its frames come from a work queue whose frames any replica may take (`--consume` on RabbitMQ or MQTT): when
    # this netapp takes its next frame says nothing of when the robot's next frame is taken, so its results carry
    # no `next_frame_in_ms`
    frames_spread: bool = False

    def weigh(self, size_bytes: int) -> None:
        """A frame of `size_bytes` arrived (its bytes already bounded by the transport)."""
        if size_bytes > 0:
            self.frame_bytes = smoothed(self.frame_bytes or None, size_bytes, 0.2)

    @property
    def needs_fps(self) -> float | None:
        """The results per second its robot said it needs (`NEEDS_FIELD` in its INIT data or /register args)."""
        value = self.args.get(NEEDS_FIELD)
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
        return float(value) if ok else None

    @property
    def label(self) -> str:
        """The `transport` label of its metrics: what its frames arrive as."""
        return self.streams or self.transport

    def cost(self, seconds: float, alpha: float = 0.2) -> None:
        """One of its frames cost the inference thread `seconds` (called there; read on the event loop)."""
        self.cost_s = smoothed(self.cost_s or None, seconds, alpha)

    def touch(self) -> None:
        """The robot is still there (idle sessions expire)."""
        self.last_seen = time.monotonic()

    def admit(self, transport: str) -> None:
        """Count a received frame (see `FrameCounter.received`, the one place that calls this)."""
        self.received += 1
        self.streams = transport
        self.touch()
        self.rate.arrived(self.last_seen)

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
            "transport": self.label,
            "robot_id": self.robot_id,
            "received": self.received,
            "processed": self.processed,
            "dropped": self.dropped,
            "deadline_dropped": self.deadline_dropped,
            "rejected": self.rejected,
        }


TOKEN_TRANSPORT = "http"  # sessions named by a signed token (POST /register), good on any replica
REVOKED_KEPT = 10_000  # unregistered HTTP tokens remembered (refused); the oldest are forgotten first
LIFETIME_ALPHA = 0.1  # weight of an ended session's lifetime in the moving average


class SessionRegistry:
    """All live sessions by id, up to `limit()` of them (None: no limit), and the HTTP tokens unregistered here (a
    token is otherwise good anywhere)."""

    def __init__(
        self, results_buffer: int, limit: Callable[[], tuple[int, str]] | None = None, live_s: float = math.inf
    ) -> None:
        self.results_buffer = results_buffer
        self.limit = limit or (lambda: (sys.maxsize, "no limit"))  # (sessions, why that many)
        self.live_s = live_s  # an HTTP session without a request for this long no longer counts against the limit
        self._sessions: dict[str, Session] = {}
        self._revoked: OrderedDict[str, None] = OrderedDict()
        # how long the sessions admitted here lasted, a moving average (None before one ended): when a full netapp
        # expects the next to end (`netapp.server.retry_after`)
        self.mean_lifetime_s: float | None = None

    def create(
        self,
        transport: str,
        robot_id: str | None = None,
        args: dict[str, Any] | None = None,
        session_id: str | None = None,
        state: Any = None,
        admit: bool = True,
    ) -> Session:
        """A new session; SessionsFull when `admit` and the netapp already holds `limit()` live sessions. Without
        `admit`: a record of a session admitted elsewhere (an HTTP token), never refused nor counted."""
        if admit:
            limit, why = self.limit()
            live = self.live()
            if live >= limit:
                raise SessionsFull(limit, why, sessions_retry_after_s(live, self.mean_lifetime_s))
        session = Session(
            id=session_id or uuid.uuid4().hex,
            transport=transport,
            robot_id=robot_id,
            args=dict(args or {}),
            results_buffer=self.results_buffer,
            state=state,
            admitted=admit,
        )
        self._sessions[session.id] = session
        return session

    def get(self, session_id: str | None) -> Session | None:
        return self._sessions.get(session_id) if session_id else None

    def revoked(self, session_id: str) -> bool:
        return session_id in self._revoked

    def remove(self, session_id: str, *, revoke: bool = False) -> Session | None:
        if revoke:
            self._revoked[session_id] = None
            while len(self._revoked) > REVOKED_KEPT:
                self._revoked.popitem(last=False)
        session = self._sessions.pop(session_id, None)
        if session is not None:
            session.closed = True
            if session.admitted:
                self._ended(time.monotonic() - session.opened_s)
        return session

    def _ended(self, lifetime_s: float) -> None:
        self.mean_lifetime_s = smoothed(self.mean_lifetime_s, lifetime_s, LIFETIME_ALPHA)

    def idle(self, ttl_s: float, transport: str) -> list[Session]:
        cutoff = time.monotonic() - ttl_s
        return [s for s in self._sessions.values() if s.transport == transport and s.last_seen < cutoff]

    def __iter__(self) -> Iterator[Session]:
        return iter(list(self._sessions.values()))

    def count(self, label: str) -> int:
        return sum(1 for s in self._sessions.values() if s.label == label)

    def live(self) -> int:
        """Sessions admitted here that are live: one on a connection (Socket.IO, `frames`, WebRTC, a camera) while it
        is open, an HTTP one while its robot has made a request within `live_s` (its record stays until it expires)."""
        cutoff = time.monotonic() - self.live_s
        live = (s for s in self._sessions.values() if s.transport != TOKEN_TRANSPORT or s.last_seen >= cutoff)
        return sum(1 for s in live if s.admitted)

    def __len__(self) -> int:
        return len(self._sessions)

    def input_rates(self, now_s: float) -> list[float]:
        """The rate each session is to be served at (results per second): what its robot said it needs, else the
        input rate of a session that is streaming."""
        rates = (s.needs_fps or s.rate.fps(now_s) for s in self._sessions.values())
        return [r for r in rates if r is not None]
