"""Where a sleeping netapp is reached while it sleeps (its URL unchanged): every request there is answered 503
`waking` with `Retry-After: 0` and asks for the wake, so a robot that still holds the URL is told to wait, not refused
for good; its client tries again on a short schedule (netapp.client.link's WAKE_RETRY_S), through the moment the
netapp answers there again. The middleware's local backend listens on a sleeping process' port; on Kubernetes the
operator's waker (netapp_operator.waker) is the endpoint of every sleeping NetApp's Service.

Every byte is a stranger's: the request's head is read up to MAX_HEAD_BYTES for READ_TIMEOUT_S at most, and past
MAX_CONNECTIONS at once a connection is closed unanswered (counted in `refused`).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Callable

from netapp.protocol import WAKING_REASON, error_body

MAX_HEAD_BYTES = 16 * 1024  # the request's head is read (and dropped) so that the client reads the answer
READ_TIMEOUT_S = 2.0
MAX_CONNECTIONS = 256  # answered at once; more are closed unanswered (robots retry)


def http_answer(status: str, message: str, reason: str, retry_after: bool = False) -> bytes:
    """An HTTP/1.1 answer with the project's JSON error body, closing the connection."""
    body = json.dumps(error_body(message, reason)).encode()
    retry = "Retry-After: 0\r\n" if retry_after else ""
    head = (
        f"HTTP/1.1 {status}\r\nContent-Type: application/json\r\n{retry}"
        f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n"
    )
    return head.encode() + body


def waking_answer() -> bytes:
    """The 503 every request gets while the netapp wakes."""
    return http_answer(
        "503 Service Unavailable", "the netapp is waking from zero: try again in a moment", WAKING_REASON, True
    )


def host_of(head: bytes) -> str:
    """The request's Host header, lower-case ("" when there is none or the head is not HTTP)."""
    for line in head.split(b"\r\n")[1:]:
        name, sep, value = line.partition(b":")
        if sep and name.strip().lower() == b"host":
            return value.strip().decode("latin-1").lower()
    return ""


class WakeListener:
    """Listens on host:port; each request's head (b"" when it did not come whole in time) goes to `answer`, called
    on the loop, which asks for the wake and returns the bytes to answer with."""

    def __init__(self, answer: Callable[[bytes], bytes]) -> None:
        self.answer = answer
        self.refused = 0  # connections closed unanswered: over MAX_CONNECTIONS
        self._open = 0
        self._server: asyncio.base_events.Server | None = None

    @property
    def port(self) -> int | None:
        server = self._server
        return None if server is None or not server.sockets else int(server.sockets[0].getsockname()[1])

    async def open(self, host: str, port: int) -> None:
        self._server = await asyncio.start_server(self._answer, host, port, limit=MAX_HEAD_BYTES)

    async def close(self) -> None:
        """Stop listening (the port is free for the netapp again once this returns)."""
        server, self._server = self._server, None
        if server is not None:
            server.close()
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(server.wait_closed(), READ_TIMEOUT_S)

    async def _answer(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._open >= MAX_CONNECTIONS:
            self.refused += 1
            writer.close()
            return
        self._open += 1
        try:
            head = b""
            with contextlib.suppress(asyncio.TimeoutError, asyncio.LimitOverrunError, asyncio.IncompleteReadError):
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), READ_TIMEOUT_S)
            writer.write(self.answer(head))
            await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            self._open -= 1
            writer.close()
