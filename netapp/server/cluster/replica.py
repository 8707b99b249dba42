"""One replica among many behind a Service: it forwards what another replica owns, and drains on its way out.

The ASGI app in front of Socket.IO, the `frames` endpoint and FastAPI. For each request or WebSocket it asks who owns
the session (`netapp.server.cluster.ownership`): another replica, and the request goes there
(`netapp.server.cluster.forwarding`); this one, or nobody in particular, and it is served here.

Draining (SIGTERM: scale-down, rolling update, node drain): readiness answers 503 at once, so the Service sends no new
connections; new robots are refused with 503 `draining` and `Retry-After`; every robot this replica serves or relays
hears `move` (on /control, or a `frames` event) and reconnects through the Service; HTTP answers close their connection
so a robot's next request opens one to a ready replica. The replica exits once its robots have moved, its requests are
answered and its polled results fetched, or when the grace period ends.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs

from netapp.framing import FRAMES_PATH
from netapp.protocol import CONTROL_NAMESPACE, DRAINING_REASON, FORWARDED_HEADER, MOVE_EVENT, SESSION_HEADER, error_body
from netapp.server.asgi_scope import header
from netapp.server.cluster.forwarding import Forwarder, answer
from netapp.server.services import NetAppServices
from netapp.startup import SOCKETIO_CLIENTS, deferred

with deferred(*SOCKETIO_CLIENTS):  # not the server's (netapp.startup)
    import socketio

if TYPE_CHECKING:
    from netapp.server.frames.endpoint import FramesEndpoint

log = logging.getLogger(__name__)

FORWARDED = FORWARDED_HEADER.lower().encode()
SESSION = SESSION_HEADER.lower().encode()
DRAIN_POLL_S = 0.05
MOVE_NOTICE = {"reason": DRAINING_REASON, "message": "this replica is going away: reconnect through the Service"}
TRUE_VALUES = ("1", "true", "yes", "on")


def needs_owner(path: str, query: dict[str, list[str]], stateful: bool = False) -> bool:
    """HTTP requests about polled results go to the session's owner, where those results are kept; so does every
    frame of a stateful processor's session (its state lives with the owner, updated in frame order)."""
    if path in ("/results", "/unregister"):
        return True
    return path == "/send_image" and (stateful or (query.get("wait") or ["false"])[0].lower() not in TRUE_VALUES)


def is_handshake(scope: dict[str, Any]) -> bool:
    """An Engine.IO request that opens a session (it names none): a new robot."""
    return b"sid=" not in scope.get("query_string", b"")


def closing(send: Any) -> Any:
    """`send` that asks the client to close the connection after this answer (its next one lands elsewhere)."""

    async def send_and_close(message: dict[str, Any]) -> None:
        if message["type"] == "http.response.start":
            headers = [(k, v) for k, v in message.get("headers", []) if k.lower() != b"connection"]
            message = {**message, "headers": [*headers, (b"connection", b"close")]}
        await send(message)

    return send_and_close


class ReplicaApp(socketio.ASGIApp):
    def __init__(
        self, sio: socketio.AsyncServer, api: Any, services: NetAppServices, frames: FramesEndpoint | None = None
    ) -> None:
        super().__init__(sio, other_asgi_app=api)
        self.sio = sio
        # The `frames` WebSockets: one per robot, served where it lands (its session lives there, as a Socket.IO
        # robot's does), never forwarded; it refuses new robots itself while draining, saying why.
        self.frames = frames
        self.services = services
        assert services.peers is not None  # NetAppServices.build makes it
        self.forwarder = Forwarder(services.settings.transport_limit_bytes, services.metrics.forwarded, services.peers)
        self.answering = 0  # HTTP requests being answered or forwarded (not Engine.IO's own: those are robots)
        default_sid = sio.eio.generate_id
        sio.eio.generate_id = lambda: services.cluster.engineio_sid(default_sid())

    def is_engineio(self, scope: dict[str, Any]) -> bool:
        return self._ensure_trailing_slash(scope["path"]).startswith(self.engineio_path)

    def remote_owner(self, scope: dict[str, Any]) -> str | None:
        """The replica this request or WebSocket belongs to, when that is not this one."""
        cluster = self.services.cluster
        if not cluster.shared or header(scope, FORWARDED) is not None:
            return None
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        if self.is_engineio(scope):
            return cluster.remote(cluster.engineio_owner((query.get("sid") or [None])[0]))
        stateful = self.services.stateful
        if scope["type"] == "http" and needs_owner(scope["path"], query, stateful):
            claims = cluster.open_session_token(header(scope, SESSION))
            return cluster.remote(claims.owner) if claims is not None else None
        return None

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        kind = scope["type"]
        if kind == "websocket" and self.frames is not None and scope["path"] == FRAMES_PATH:
            await self.frames(scope, receive, send)
        elif kind == "websocket":
            await self._websocket(scope, receive, send)
        elif kind == "http" and self.is_engineio(scope):
            await self._engineio_http(scope, receive, send)
        elif kind == "http":
            owner = self.remote_owner(scope)
            with self._answering():
                if owner is not None:
                    await self.forwarder.http(owner, scope, receive, self._http_send(send))
                else:
                    await super().__call__(scope, receive, self._http_send(send))
        else:
            await super().__call__(scope, receive, send)

    async def _engineio_http(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        owner = self.remote_owner(scope)
        if owner is not None:
            with self._answering():  # a relayed long-poll cut by the exit would take its packets with it
                await self.forwarder.http(owner, scope, receive, self._http_send(send))
        elif self.services.draining and is_handshake(scope):
            await self._refuse_new_robot("http", receive, send)
        else:  # this replica's own robots: counted as robots while draining
            await super().__call__(scope, receive, self._http_send(send))

    @contextlib.contextmanager
    def _answering(self) -> Iterator[None]:
        """A request being answered or forwarded: a draining replica exits only once it is done."""
        self.answering += 1
        try:
            yield
        finally:
            self.answering -= 1

    def _http_send(self, send: Any) -> Any:
        """While draining, every HTTP answer closes its connection: the client's next one lands elsewhere."""
        return closing(send) if self.services.draining else send

    async def _websocket(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        owner = self.remote_owner(scope)
        if owner is not None:
            await self.forwarder.websocket(owner, scope, receive, send)
        elif self.services.draining and is_handshake(scope):
            await self._refuse_new_robot("websocket", receive, send)
        else:
            await super().__call__(scope, receive, send)

    async def _refuse_new_robot(self, kind: str, receive: Any, send: Any) -> None:
        if kind == "websocket":
            await receive()
            await send({"type": "websocket.close", "code": 1013})  # try again later (elsewhere)
            return
        body = error_body("this replica is draining: connect again through the Service", DRAINING_REASON)
        await answer(send, 503, body, {"Retry-After": "1", "Connection": "close"})

    # -- draining ---------------------------------------------------------------------------------------------

    def waiting_for(self) -> dict[str, int]:
        """What a draining replica still waits for: Socket.IO and `frames` robots here, relayed ones, answers, polled
        results."""
        return {
            "robots": len(self.sio.eio.sockets) + self._frames_robots(),
            "relayed": len(self.forwarder.relayed),
            "answers": self.answering,
            "unpolled": sum(1 for s in self.services.sessions if s.transport == "http" and s.results),
        }

    def _frames_robots(self) -> int:
        return len(self.frames.connections) if self.frames is not None else 0

    def drained(self) -> bool:
        return not any(self.waiting_for().values())

    async def drain(self) -> None:
        """Stop taking robots, tell those here to move, and return once they have (or the grace period ended)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.services.settings.drain_grace_s
        self.services.draining = True
        robots = len(self.sio.eio.sockets) + len(self.forwarder.relayed) + self._frames_robots()
        log.info("draining: %d WebSocket robots told to move", robots)
        await self.sio.emit(MOVE_EVENT, MOVE_NOTICE, namespace=CONTROL_NAMESPACE)
        if self.frames is not None:
            self.frames.move_all(MOVE_NOTICE)
        await self.forwarder.move_relayed(MOVE_NOTICE)
        while not self.drained() and loop.time() < deadline:
            await asyncio.sleep(DRAIN_POLL_S)  # polling what the robots do, with the grace period as deadline
        if self.drained():
            log.info("drained: every robot has moved")
        else:
            log.warning("grace period over, still waiting for %s", self.waiting_for())
