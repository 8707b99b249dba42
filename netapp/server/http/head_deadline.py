"""uvicorn's httptools protocol with bounds on each request head: a deadline, and a size.

uvicorn closes a keep-alive connection idle after a response (`timeout_keep_alive`), but waits forever for the
head (request line and headers) of a connection's first request, and for one that is half sent: 1,500 idle
connections and 200 half-sent requests were all held open. Here each connection must deliver each request head
within `head_timeout_s`, or it is closed; and a head over `MAX_HEAD_BYTES` is refused (400) before more of it is
kept. Bodies have their own deadline where they are read (the HTTP routes).

httptools (llhttp, in C) rather than h11: 0.2 to 0.4 ms less a frame over HTTP (docs/benchmarks.md, "The fifth step
together"). h11 bounded a head by itself (`h11_max_incomplete_event_size`); httptools keeps what it is given, so the
bound is here.
"""

from __future__ import annotations

import asyncio
import logging

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

log = logging.getLogger(__name__)

MAX_HEAD_BYTES = 16 * 1024  # a request line and its headers (uvicorn's h11 default was 16 KiB too)
HEAD_TOO_LARGE = "the request head (request line and headers) is over {} bytes: send fewer or shorter headers"


def bounded_http_protocol(head_timeout_s: float, max_head_bytes: int = MAX_HEAD_BYTES) -> type[HttpToolsProtocol]:
    """An HttpToolsProtocol class (uvicorn's `http` option) that closes connections slow to send a request head and
    refuses a head over `max_head_bytes`."""

    class BoundedHttpToolsProtocol(HttpToolsProtocol):
        _head_deadline: asyncio.TimerHandle | None = None
        _in_head = True  # between requests, or partway through a head
        _head_bytes = 0  # of the head so far, in the chunks that did not finish it
        _fields_bytes = 0  # of its request line and headers as parsed (a whole head may come in one chunk)
        _head_too_large = False

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm_head_deadline()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm_head_deadline()
            super().connection_lost(exc)

        def data_received(self, data: bytes) -> None:
            in_head = self._in_head
            super().data_received(data)
            if not (in_head and self._in_head) or self.transport.is_closing():
                return  # the head ended in this chunk (what follows is the body's), or the connection is done
            self._head_bytes += len(data)
            if self._head_bytes > max_head_bytes:
                self._refuse_head()
                self.send_400_response("")  # says why (`send_400_response`)

        def on_message_begin(self) -> None:
            super().on_message_begin()
            # a head starts (pipelined, maybe before the last response)
            self._in_head, self._head_bytes, self._fields_bytes = True, 0, 0

        def on_url(self, url: bytes) -> None:
            self._count_field(len(url))
            super().on_url(url)

        def on_header(self, name: bytes, value: bytes) -> None:
            self._count_field(len(name) + len(value) + 4)  # ": " and CRLF
            super().on_header(name, value)

        def _count_field(self, size: int) -> None:
            """Past the bound, an error out of a parser callback: uvicorn answers it with a 400 and closes."""
            self._fields_bytes += size
            if self._fields_bytes > max_head_bytes:
                self._refuse_head()
                raise ValueError(HEAD_TOO_LARGE.format(max_head_bytes))

        def _refuse_head(self) -> None:
            self._head_too_large = True
            log.info("refusing a request from %s: its head is over %d bytes", self.client, max_head_bytes)

        def send_400_response(self, msg: str) -> None:
            # uvicorn's answer to any parser error says "Invalid HTTP request received."; a head too large says so
            super().send_400_response(HEAD_TOO_LARGE.format(max_head_bytes) if self._head_too_large else msg)

        def on_headers_complete(self) -> None:
            self._in_head = False
            self._disarm_head_deadline()  # a head arrived: the request is the app's now
            super().on_headers_complete()

        def handle_websocket_upgrade(self) -> None:
            self._disarm_head_deadline()
            super().handle_websocket_upgrade()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
                self._in_head, self._head_bytes = True, 0
                self._arm_head_deadline()  # the next request's head

        def _arm_head_deadline(self) -> None:
            self._disarm_head_deadline()
            self._head_deadline = self.loop.call_later(head_timeout_s, self._head_timed_out)

        def _disarm_head_deadline(self) -> None:
            if self._head_deadline is not None:
                self._head_deadline.cancel()
                self._head_deadline = None

        def _head_timed_out(self) -> None:
            self._head_deadline = None
            if self.transport.is_closing() or self.transport.get_protocol() is not self:
                return  # closed already, or upgraded to a WebSocket
            if self.cycle is not None and not self.cycle.response_complete:
                return  # a request is in progress
            log.info(
                "closing a connection from %s: no complete request head within %.0f s", self.client, head_timeout_s
            )
            self.transport.close()

    return BoundedHttpToolsProtocol
