"""uvicorn's h11 protocol with a deadline on each request head.

uvicorn closes a keep-alive connection idle after a response (`timeout_keep_alive`), but waits forever for the
head (request line and headers) of a connection's first request, and for one that is half sent: 1,500 idle
connections and 200 half-sent requests were all held open. Here each connection must deliver each request head
within `head_timeout_s`, or it is closed. Bodies have their own deadline where they are read (the HTTP routes).
"""

from __future__ import annotations

import asyncio
import logging

from uvicorn.protocols.http.h11_impl import H11Protocol

log = logging.getLogger(__name__)


def timed_h11_protocol(head_timeout_s: float) -> type[H11Protocol]:
    """An H11Protocol class (uvicorn's `http` option) that closes connections slow to send a request head."""

    class TimedH11Protocol(H11Protocol):
        _head_deadline: asyncio.TimerHandle | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm_head_deadline()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm_head_deadline()
            super().connection_lost(exc)

        def handle_events(self) -> None:
            super().handle_events()
            if self.cycle is not None and not self.cycle.response_complete:
                self._disarm_head_deadline()  # a head arrived: the request is the app's now

        def handle_websocket_upgrade(self, event) -> None:  # type: ignore[no-untyped-def]
            self._disarm_head_deadline()
            super().handle_websocket_upgrade(event)

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
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

    return TimedH11Protocol
