"""Where a sleeping local netapp listened (its URL unchanged): every request there wakes it and is answered 503
`waking` with `Retry-After: 0`, so a robot that still holds the URL is told to wait, not refused for good; its client
tries again on a short schedule (netapp.client.link's WAKE_RETRY_S), through the moment the port is handed back to
the netapp process starting there.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Callable

from netapp.protocol import WAKING_REASON, error_body

MAX_HEAD_BYTES = 16 * 1024  # the request's head is read (and dropped) so that the client reads the answer
READ_TIMEOUT_S = 2.0


def waking_answer() -> bytes:
    """The 503 every request gets while the netapp wakes (HTTP/1.1, closing the connection)."""
    body = json.dumps(error_body("the netapp is waking from zero: try again in a moment", WAKING_REASON)).encode()
    head = (
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\nRetry-After: 0\r\n"
        f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n"
    )
    return head.encode() + body


class WakeListener:
    """Listens on host:port while the netapp sleeps; `on_request` is called (on the loop) at each request."""

    def __init__(self, on_request: Callable[[], None]) -> None:
        self.on_request = on_request
        self._server: asyncio.base_events.Server | None = None

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
        self.on_request()
        try:
            with contextlib.suppress(asyncio.TimeoutError, asyncio.LimitOverrunError, asyncio.IncompleteReadError):
                await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), READ_TIMEOUT_S)
            writer.write(waking_answer())
            await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            writer.close()
