"""Forwarding to the owner: requests and WebSockets of a session another replica owns go to that replica.

The owner's address comes only from an id signed with the replicas' shared key (`netapp.server.cluster.ownership`),
never from anything else a client sends, so a client cannot make a replica connect to an address of its choosing. A
forwarded request carries `X-Netapp-Forwarded` and is never forwarded again. Bodies are bounded as on the owner.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from prometheus_client import Counter
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import WebSocketException

from netapp.protocol import CONTROL_NAMESPACE, FORWARDED_HEADER, MOVE_EVENT, error_body
from netapp.server.cluster.peer_tls import PeerTLS

log = logging.getLogger(__name__)

HOP_BY_HOP = frozenset(
    {b"connection", b"keep-alive", b"proxy-authenticate", b"proxy-authorization", b"te", b"trailer"}
    | {b"transfer-encoding", b"upgrade", b"host"}
)
FORWARDED = FORWARDED_HEADER.lower().encode()
# An Engine.IO long-poll waits up to its ping interval (25 s) plus ping timeout (20 s) for something to send.
READ_TIMEOUT_S = 60.0
CONNECT_TIMEOUT_S = 2.0


def socketio_packet(namespace: str, event: str, data: Any) -> str:
    """A Socket.IO event as one Engine.IO WebSocket text frame ("4" message, "2" event), to tell a client whose
    WebSocket this replica only relays something of its own (the `move` of a draining replica)."""
    return f"42{namespace},{json.dumps([event, data], separators=(',', ':'))}"


async def answer(send: Any, status: int, body: dict[str, Any], headers: dict[str, str] | None = None) -> None:
    """A JSON answer straight from the ASGI layer (before FastAPI), in the one error body shape."""
    payload = json.dumps(body).encode()
    raw = [(b"content-type", b"application/json"), (b"content-length", str(len(payload)).encode())]
    raw += [(k.lower().encode(), v.encode()) for k, v in (headers or {}).items()]
    await send({"type": "http.response.start", "status": status, "headers": raw})
    await send({"type": "http.response.body", "body": payload})


ENGINEIO_UPGRADE = "5"  # the client's last packet of an Engine.IO upgrade: from now on it reads this WebSocket


class RelayedSocket:
    """A client's WebSocket this replica relays to its owner; `tell` slips a packet of our own into it."""

    def __init__(self, send: Any) -> None:
        self._send = send
        self._lock = asyncio.Lock()
        self.upgraded = False  # a client ignores packets on a WebSocket it is still probing

    async def send(self, message: dict[str, Any]) -> None:
        async with self._lock:
            await self._send(message)

    async def tell(self, text: str) -> None:
        with contextlib.suppress(Exception):  # the client may be gone already
            await self.send({"type": "websocket.send", "text": text})


if TYPE_CHECKING:  # imported on first use: most netapps are no cluster, and httpx costs their start-up 50 ms
    import httpx


class Forwarder:
    def __init__(self, max_body_bytes: int, counter: Counter, peers: PeerTLS) -> None:
        self.max_body_bytes = max_body_bytes
        self.counter = counter  # labelled by kind: http, websocket
        self.peers = peers  # TLS to owners that advertise https://
        self.relayed: set[RelayedSocket] = set()
        self.notice: str | None = None  # a packet for every relayed client (a draining replica's `move`)
        self._client: httpx.AsyncClient | None = None

    def client(self) -> httpx.AsyncClient:
        import httpx

        if self._client is None:  # made on the server's event loop, on first use
            timeout = httpx.Timeout(READ_TIMEOUT_S, connect=CONNECT_TIMEOUT_S)
            limits = httpx.Limits(max_keepalive_connections=32)
            self._client = httpx.AsyncClient(timeout=timeout, limits=limits, verify=self.peers.verify)
        return self._client

    async def close(self) -> None:
        if self._client is not None:
            await self._client.aclose()
            self._client = None

    async def move_relayed(self, data: Any) -> None:
        """Tell every client this replica relays, now and from now on, to move (a /control `move` event): their
        WebSockets run through a replica that is going away. One still upgrading hears it once upgraded."""
        self.notice = socketio_packet(CONTROL_NAMESPACE, MOVE_EVENT, data)
        await asyncio.gather(*(socket.tell(self.notice) for socket in list(self.relayed) if socket.upgraded))

    # -- HTTP -----------------------------------------------------------------------------------------------------

    async def http(self, owner: str, scope: dict[str, Any], receive: Any, send: Any) -> None:
        import httpx

        body = await self._read_body(receive)
        if body is None:
            limit = self.max_body_bytes
            await answer(send, 413, error_body(f"body over the {limit}-byte limit", "payload_too_large"))
            return
        url = owner + scope["path"] + (f"?{scope['query_string'].decode()}" if scope.get("query_string") else "")
        headers = [(k, v) for k, v in scope["headers"] if k.lower() not in HOP_BY_HOP] + [(FORWARDED, b"1")]
        started = False
        self.counter.labels(kind="http").inc()
        try:
            request = self.client().build_request(scope["method"], url, headers=headers, content=body)
            response = await self.client().send(request, stream=True)
            try:
                raw = [(k, v) for k, v in response.headers.raw if k.lower() not in HOP_BY_HOP]
                await send({"type": "http.response.start", "status": response.status_code, "headers": raw})
                started = True
                async for chunk in response.aiter_raw():
                    await send({"type": "http.response.body", "body": chunk, "more_body": True})
                await send({"type": "http.response.body", "body": b""})
            finally:
                await response.aclose()
        except httpx.HTTPError as exc:
            if not self.peers.refused(owner, exc):
                log.warning("the owner %s of a session did not answer: %s", owner, exc)
            if not started:
                message = "the replica that holds this session is gone: register (or connect) again"
                await answer(send, 503, error_body(message, "owner_gone"), {"Retry-After": "0"})

    async def _read_body(self, receive: Any) -> bytes | None:
        """The request body, or None past the limit (read no further)."""
        chunks, size = [], 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                return b"".join(chunks)
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_body_bytes:
                return None
            chunks.append(chunk)
            if not message.get("more_body"):
                return b"".join(chunks)

    # -- WebSocket ------------------------------------------------------------------------------------------------

    async def websocket(self, owner: str, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if (await receive())["type"] != "websocket.connect":
            return
        parts = urlsplit(owner)
        url = f"{'wss' if parts.scheme == 'https' else 'ws'}://{parts.netloc}{scope['path']}"
        url += f"?{scope['query_string'].decode()}" if scope.get("query_string") else ""
        try:
            upstream = await connect(
                url,
                additional_headers={FORWARDED_HEADER: "1"},
                max_size=self.max_body_bytes,
                open_timeout=CONNECT_TIMEOUT_S,
                ping_interval=None,  # Engine.IO pings through the relay itself
                compression=None,
                ssl=self.peers.websocket_ssl(url),
            )
        except (OSError, TimeoutError, WebSocketException) as exc:
            if not self.peers.refused(owner, exc):
                log.warning("the owner %s of a session refused its WebSocket: %s", owner, exc)
            await send({"type": "websocket.close", "code": 1011})
            return
        self.counter.labels(kind="websocket").inc()
        relayed = RelayedSocket(send)
        await relayed.send({"type": "websocket.accept"})
        self.relayed.add(relayed)
        try:
            await _first_to_end(self._client_to_owner(receive, upstream, relayed), _owner_to_client(upstream, relayed))
        finally:
            self.relayed.discard(relayed)
            await upstream.close()
            with contextlib.suppress(Exception):
                await relayed.send({"type": "websocket.close", "code": 1000})

    async def _client_to_owner(self, receive: Any, upstream: ClientConnection, relayed: RelayedSocket) -> None:
        while True:
            message = await receive()
            if message["type"] != "websocket.receive":
                return
            text = message.get("text")
            await upstream.send(text if text is not None else message.get("bytes") or b"")
            if text == ENGINEIO_UPGRADE and not relayed.upgraded:
                relayed.upgraded = True
                if self.notice is not None:
                    await relayed.tell(self.notice)


async def _owner_to_client(upstream: ClientConnection, relayed: RelayedSocket) -> None:
    with contextlib.suppress(WebSocketException):
        async for data in upstream:
            key = "text" if isinstance(data, str) else "bytes"
            await relayed.send({"type": "websocket.send", key: data})


async def _first_to_end(*coroutines: Any) -> None:
    """Run the two directions of a relay until either ends; the other is cancelled."""
    tasks = [asyncio.ensure_future(c) for c in coroutines]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
