"""The netapp's operations, whatever the transport (KServe's dataplane, with thin wrappers per protocol): open a
session, submit a frame, the state commands, poll results, close a session, readiness.

Every transport (HTTP, Socket.IO, frames, RTP, WebRTC, the cameras) only converts its wire format to and from an
`EncodedFrame` (`netapp.frame`) at its edge, calls one of these and maps what it raises (`netapp.server.errors`) to
a status code or an error event; it uses these methods only, never the services or the pipeline behind them. Each
transport's connection is one `Connection` (`netapp.server.connection`), registered here (`connect`, `open_session`)
and closed in one place (`disconnect`, `close_session`). Every frame is counted inside (`submit`: received, then
rejected or queued), never by a transport.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from netapp.frame import EncodedFrame
from netapp.protocol import DRAINING_REASON, PRIORITY_CLASSES, PRIORITY_FIELD
from netapp.sdk.session_state import StateError
from netapp.server.connection import Connection
from netapp.server.errors import FrameRejected, RequestRefused, ResultTimeout, SessionClosed, SessionsFull, draining
from netapp.server.pipeline import hints
from netapp.server.pipeline.frame import ResultSink
from netapp.server.pipeline.observers import ResultObserver
from netapp.server.pipeline.priorities import HIGHEST, robot_priority
from netapp.server.pipeline.state_keeper import SessionState
from netapp.server.retry_after import queue_retry_after_s
from netapp.server.services import NetAppServices
from netapp.server.sessions import TOKEN_TRANSPORT, Session
from netapp.tracecontext import TRACEPARENT, TRACESTATE

log = logging.getLogger(__name__)


PICTURE = "picture"  # the codec of a picture decoded at its edge (a camera's, a WebRTC track's): no payload here
LATENCY_META = "latency"  # the robot's report of its previous result's uplink and downlink, in a frame's metadata


@dataclass(frozen=True)
class IncomingFrame:
    """A frame as a transport parsed it: what came over the wire, as the one frame type (`frame`, checked at the
    transport's edge), and its decoding, not yet run."""

    frame: EncodedFrame
    decode: Callable[[], np.ndarray]
    in_order: bool = False  # video: decoded on its lane, after the frames before it (`FrameDecoder.in_order`)
    picture_bytes: int = 0  # a `picture`: what its packet weighed on the wire

    @classmethod
    def picture(
        cls, timestamp: int, decode: Callable[[], np.ndarray], size_bytes: int = 0, in_order: bool = False
    ) -> IncomingFrame:
        """A picture its edge decoded already (a camera's reader, aiortc): its decoding only converts it."""
        return cls(EncodedFrame(PICTURE, timestamp, b""), decode, in_order, size_bytes)

    @property
    def timestamp(self) -> int:
        return self.frame.timestamp

    @property
    def deadline_ms(self) -> float | None:
        """The robot's deadline for it, from its receipt."""
        return self.frame.deadline_ms

    @property
    def size_bytes(self) -> int:
        """What it weighed on the wire (a JPEG, an H.264 access unit, a camera's packet)."""
        return self.frame.size or self.picture_bytes

    def meta(self, name: str) -> Any:
        """One field of its metadata (the robot's `latency` report; the W3C trace context, unparsed: read only when
        tracing is on, docs/tracing.md), None where absent."""
        return self.frame.meta.get(name) if self.frame.meta else None


@dataclass(frozen=True)
class Accepted:
    """A frame in the pipeline: its timestamp, and with `wait` the future its result (or FrameError) comes on."""

    timestamp: int
    waiter: asyncio.Future | None


class DataPlane:
    def __init__(self, services: NetAppServices) -> None:
        self.services = services
        self.pipeline = services.pipeline
        self.settings = services.settings
        self._connections: dict[str, Connection] = {}  # by key: every transport's, and the cameras'

    def observe(self, observer: ResultObserver) -> None:
        """Tell `observer` of every delivered result, robot report and closed session (the web page's live view)."""
        self.pipeline.observers.add(observer)

    # -- sessions ---------------------------------------------------------------------------------------------------

    def open_session(
        self,
        transport: str,
        robot_id: str | None,
        args: dict[str, Any],
        *,
        session_id: str | None = None,
        admit: bool = True,
        granted: int | None = None,
        connection: Connection | None = None,
    ) -> Session:
        """A new session (with a stateful processor, its state from `args`); RequestRefused for bad arguments (a
        priority class above `granted`, the class its token grants, among them), SessionsFull past the admission
        limit (`admit`: a robot admitted here, not a record of a token, whose class was checked where it was).
        `connection`: the connection it belongs to, keyed by the session's id from now on."""
        priority = robot_priority(args, self.settings.robot_priority if granted is None else granted)
        try:
            state = self.pipeline.keeper.open(args)
        except ValueError as exc:
            raise RequestRefused("invalid_request", str(exc), 422) from exc
        try:
            session = self.services.sessions.create(
                transport, robot_id=robot_id, args=args, state=state, session_id=session_id, admit=admit
            )
        except SessionsFull:
            self.services.metrics.sessions_refused.inc()
            raise
        session.priority = priority
        if connection is not None:
            self._connections.pop(connection.key, None)
            connection.key, connection.session = session.id, session
            self._connections[session.id] = connection
        return session

    def register(
        self,
        robot_id: str | None,
        args: dict[str, Any],
        granted: int | None = None,
        connection: Connection | None = None,
    ) -> Session:
        """A session whose id is a token signed by the replicas (`netapp.server.cluster.ownership`): any replica
        behind the Service opens it on its first request (`token_session`). Its priority class, checked here
        against `granted`, is signed into the token, so every replica gives it the same."""
        if self.services.draining:
            raise draining("this replica is draining: register again through the Service")
        granted = self.settings.robot_priority if granted is None else granted
        try:
            priority = robot_priority(args, granted)
        except RequestRefused as exc:
            self.refuse(TOKEN_TRANSPORT, exc.reason)  # counted, as a refused INIT is (`bad_command`)
            raise
        args = {**args, PRIORITY_FIELD: PRIORITY_CLASSES[priority]}
        try:
            token = self.services.cluster.session_token(robot_id, args)
        except ValueError as exc:
            raise RequestRefused("args_too_large", f"{exc}: send large settings another way", 413) from exc
        return self.open_session(
            TOKEN_TRANSPORT, robot_id, args, session_id=token, granted=granted, connection=connection
        )

    def token_session(self, token: str | None) -> Session:
        """The session a token names (kept alive by each request): one first seen here is opened here (it was
        checked, and the robot admitted, when the token was issued); RequestRefused 404 when there is none."""
        sessions = self.services.sessions
        session = sessions.get(token)
        if session is None and token and not sessions.revoked(token):
            claims = self.services.cluster.open_session_token(token)
            if claims is not None:
                session = self.open_session(  # its class was checked where the token was issued
                    TOKEN_TRANSPORT, claims.robot_id, claims.args, session_id=token, admit=False, granted=HIGHEST
                )
        if session is None or session.transport != TOKEN_TRANSPORT:
            message = "unknown session: send X-Session-Id from POST /register"
            raise RequestRefused("unknown_session", message, 404, session_id=token)
        session.touch()
        return session

    def close_session(self, session: Session, reason: str, *, revoke: bool = False) -> None:
        """End a session; the waiters of its queued frames hear `reason`; its connection releases what it held for
        it (and closes, unless its wire outlives it). `revoke`: its id is refused from now on (an unregistered
        token; an idle one may come back)."""
        self.services.sessions.remove(session.id, revoke=revoke)
        self.pipeline.close(session, SessionClosed(reason))
        self.pipeline.observers.forget(session.id)
        connection = self._connections.get(session.id)
        if connection is not None and connection.session is session:
            connection.end_session()
            if connection.closed:
                del self._connections[session.id]

    # -- connections ------------------------------------------------------------------------------------------------

    def connect(self, connection: Connection) -> Connection:
        """Register a connection that has no session yet (Socket.IO and frames before INIT)."""
        self._connections[connection.key] = connection
        return connection

    def connection(self, key: str | None) -> Connection | None:
        """The connection `key` names (a session's id), if it is open."""
        return self._connections.get(key) if key is not None else None

    def connections(self, transport: str) -> list[Connection]:
        """Every open connection of one transport."""
        return [c for c in self._connections.values() if c.transport == transport]

    def disconnect(self, connection: Connection, reason: str) -> None:
        """The one close of a connection whose wire went away: its session ends (`reason`), everything it holds is
        released (its decoders, its RTP port, its subscriptions)."""
        if self._connections.get(connection.key) is connection:
            del self._connections[connection.key]
        session = connection.live_session
        if session is not None:
            self.close_session(session, reason)
        connection.close()

    def session(self, key: str | None) -> Session | None:
        """The open session `key` names, if any."""
        return self.services.sessions.get(key)

    def revoked(self, token: str | None) -> bool:
        """Whether this token was unregistered here (`netapp.server.cluster.revocation`)."""
        return bool(token) and self.services.sessions.revoked(token)

    async def unregistered_elsewhere(self, session: Session) -> bool:
        """Whether the replica that issued the session's token says its robot unregistered there (a cluster)."""
        revocations = self.services.revocations
        return revocations is not None and await revocations.revoked(session)

    def stats(self, session: Session) -> dict[str, Any]:
        """The session's counters and its queue depth (GET_STATE of a stateless netapp, /unregister)."""
        return {**session.stats(), "queue_depth": self.pipeline.depth(session)}

    def expire_idle(self) -> None:
        """Token sessions whose robot vanished without unregistering must not hold memory forever."""
        for session in self.services.sessions.idle(self.settings.session_ttl_s, TOKEN_TRANSPORT):
            log.info("closing idle HTTP session %s", session.id)
            self.close_session(session, "the session expired")

    # -- frames -----------------------------------------------------------------------------------------------------

    def refuse(self, transport: str, reason: str) -> None:
        """Count a frame (or command) refused before it named a session."""
        self.pipeline.reject(None, transport, reason)

    async def submit(
        self,
        session: Session | None,
        transport: str,
        parse: Callable[[], Awaitable[IncomingFrame]],
        *,
        recv_ns: int | None = None,
        wait: bool = False,
        sink: ResultSink | None = None,
    ) -> Accepted:
        """Count a frame and queue it: `parse` is the transport's reading and checking of it, run once the frame
        is counted and its receive order fixed. FrameRejected (counted) for a frame that cannot be taken; with
        `wait`, `result` gives what became of it, with `sink` the sink is told, else it is kept for polling."""
        recv_ns = recv_ns if recv_ns is not None else time.monotonic_ns()
        seq = self.pipeline.admit(session, transport)
        try:
            if session is not None and sink is None:
                self._check_can_hold(session, wait)
            frame = await parse()
            assert session is not None, "a transport's parse refuses a frame without a session"
            latency = frame.meta(LATENCY_META)
            if latency is not None:
                self.pipeline.observers.report(session, latency)
            session.weigh(frame.size_bytes)
            tracing = self.pipeline.tracing
            trace = tracing.begin(frame.meta(TRACEPARENT), frame.meta(TRACESTATE)) if tracing is not None else None
            waiter = await self.pipeline.receive(
                session,
                transport,
                seq,
                frame.timestamp,
                frame.decode,
                wait=wait,
                sink=sink,
                recv_ns=recv_ns,
                deadline_ms=frame.deadline_ms,
                in_order=frame.in_order,
                trace=trace,
            )
        except FrameRejected as exc:
            self.pipeline.reject(session, transport, exc.reason)
            raise
        except Exception as exc:  # a bad frame must never take the server down (5G-ERA calls os._exit here)
            log.exception("unexpected error on a frame of session %s", session.id if session else None)
            self.pipeline.reject(session, transport, "internal_error")
            raise FrameRejected("internal_error", f"internal error: {exc}", 500) from exc
        return Accepted(frame.timestamp, waiter)

    def _check_can_hold(self, session: Session, wait: bool) -> None:
        """A frame answered here and not pushed: its result is kept here (refused while draining) or waited for
        (capped per session and in all)."""
        settings = self.settings
        if self.services.draining and not wait:  # its result would be kept here, and here is going away
            raise FrameRejected(DRAINING_REASON, "this replica is draining: register again through the Service", 503)
        if wait and (
            self.services.waiting >= settings.max_waiting or session.waiting >= settings.max_waiting_per_session
        ):
            retry_s = queue_retry_after_s(self.services.waiting, self.pipeline.capacity.capacity_fps())
            raise FrameRejected(
                "too_many_waiting",
                f"too many requests wait for their result (at most {settings.max_waiting_per_session} per session, "
                f"{settings.max_waiting} in all): wait for an answer before sending more, or poll /results",
                503,
                retry_after_s=retry_s,
            )

    async def result(self, session: Session, accepted: Accepted) -> dict[str, Any]:
        """The result message of a frame submitted with `wait`; its FrameError (counted by the pipeline) else,
        ResultTimeout past `Settings.wait_timeout_s`."""
        assert accepted.waiter is not None
        self.services.waiting += 1
        session.waiting += 1
        try:
            return await asyncio.wait_for(accepted.waiter, self.settings.wait_timeout_s)
        except asyncio.TimeoutError:
            raise ResultTimeout(self.settings.wait_timeout_s) from None
        finally:
            self.services.waiting -= 1
            session.waiting -= 1

    def poll(self, session: Session) -> dict[str, Any]:
        """The results kept for a polling robot since its last poll, and its drop counters."""
        results = session.drain_results()
        return {"results": results, "dropped": session.dropped, "results_overflowed": session.results_overflowed}

    def keep(self, session: Session, message: dict[str, Any]) -> None:
        """Keep a result (or an error event) for the session's robot to poll (`GET /results`)."""
        self.pipeline.delivery.keep(session, message)

    def clear_queue(self, session: Session, why: str) -> None:
        """Drop the session's waiting frames; their waiters hear `why`."""
        self.pipeline.clear(session, FrameRejected("cleared", why))

    # -- the state commands (a stateful processor's state per session) -----------------------------------------------

    def _state(self, session: Session) -> SessionState:
        if session.state is None:
            raise RequestRefused("stateless", "this netapp's processor keeps no session state", 409)
        return session.state

    def max_state_bytes(self, session: Session) -> int:
        """The largest state `set_state` takes."""
        self._state(session)
        return self.pipeline.keeper.max_state_bytes

    async def get_state(self, session: Session) -> str:
        """The session's state as JSON text (what `set_state` takes)."""
        try:
            return await self.pipeline.keeper.get(self._state(session))
        except StateError as exc:
            raise RequestRefused("bad_state", str(exc), 500) from exc

    async def set_state(self, session: Session, data: Any) -> None:
        """Replace the session's state with `data` (a state from `get_state`, text or parsed); a bad one leaves
        the state as it was (RequestRefused 422 saying what is wrong)."""
        try:
            await self.pipeline.keeper.set(self._state(session), data)
        except StateError as exc:
            raise RequestRefused("bad_state", str(exc), 422) from exc

    async def reset_state(self, session: Session) -> None:
        """Drop the session's waiting frames and, with a stateful processor, start its state afresh."""
        self.clear_queue(session, "state reset by a command")
        if session.state is not None:
            await self.pipeline.keeper.reset(session.state, session.args)

    async def save_state(self, session: Session, name: str) -> None:
        """Save the session's state as `name` in the --state-dir volume."""
        await self._on_volume("SAVE_STATE", session, self.pipeline.keeper.save(self._state(session), name))

    async def load_state(self, session: Session, name: str) -> None:
        """Replace the session's state with the one saved as `name`."""
        await self._on_volume("LOAD_STATE", session, self.pipeline.keeper.load(self._state(session), name))

    async def _on_volume(self, command: str, session: Session, work: Awaitable[None]) -> None:
        try:
            await work
        except StateError as exc:
            raise RequestRefused("bad_state", str(exc), 422) from exc
        except OSError as exc:  # the --state-dir volume: full, read-only, gone
            log.warning("%s of session %s failed: %s", command, session.id, exc)
            message = f"{command} failed on the netapp's state volume: {exc.strerror or exc}"
            raise RequestRefused("state_volume", message, 500) from exc

    # -- what the processor is -------------------------------------------------------------------------------------

    def session_info(self) -> dict[str, Any]:
        """What a robot learns as its session opens (its processor's `input_size`): the `/register` answer, the
        Socket.IO `session_info` event."""
        return hints.session_info(self.services.processor)

    def model_metadata(self) -> dict[str, Any]:
        """The processor's metadata for `/v2` and `/v2/models/{name}`."""
        return hints.metadata(self.services.processor)

    @property
    def model_name(self) -> str:
        """The name of the model it serves (`/v2/models/{name}`)."""
        return self.services.processor.name

    # -- what a transport reports and reaches through the app --------------------------------------------------------

    @property
    def registry(self) -> Any:
        """The Prometheus registry a transport adds its own metrics to."""
        return self.services.metrics.registry

    def show_transport(self, label: str) -> None:
        """The frame counters and the sessions gauge of transport `label`, present at 0 from the start."""
        metrics, sessions = self.services.metrics, self.services.sessions
        for counter in (metrics.received, metrics.processed, metrics.dropped, metrics.deadline_dropped):
            counter.labels(transport=label)
        metrics.sessions.labels(transport=label).set_function(lambda: sessions.count(label))

    def overflowed(self) -> None:
        """Count a message dropped because its robot reads nothing (`netapp_results_overflowed`)."""
        self.services.metrics.results_overflowed.inc()

    @property
    def draining(self) -> bool:
        """This replica is going away: it takes no new robots."""
        return self.services.draining

    def peer_ssl(self, url: str) -> Any:
        """The TLS context for a WebSocket to another replica at `url` (None: plain, or no cluster TLS)."""
        peers = self.services.peers
        return peers.websocket_ssl(url) if peers is not None else None

    # -- health -----------------------------------------------------------------------------------------------------

    def check_ready(self) -> None:
        """Return when this replica takes robots; RequestRefused 503 saying why not (draining, loading, failed)."""
        if self.services.draining:
            raise draining("this replica is draining: it takes no new robots")
        if self.pipeline.ready.is_set():
            return
        if self.pipeline.load_error is not None:
            raise RequestRefused("load_failed", f"model failed to load: {self.pipeline.load_error}", 503)
        raise RequestRefused("not_ready", "model loading", 503)
