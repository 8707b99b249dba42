"""Where the Socket.IO client reaches past python-engineio's, python-socketio's and websocket-client's public API,
in one place, for the versions pinned in pyproject.toml. `tests/netapp/client/test_engineio_compat.py` checks every
name listed in `RELIES_ON` against the installed libraries, so an upgrade that moves one fails there, not on a
robot.

* `OneWayAtATimeWebSocket`, handed to websocket-client as `class_` through python-engineio's
  `websocket_extra_options`: never reads and writes a TLS socket at once (python-engineio issue #461).
* `InOrderEngineIOClient`: one dispatching thread instead of a thread per message (`_trigger_event`), and a
  polling session that closes at once (`disconnect`, `_send_packet`, `queue`, `write_loop_task`).
* `InOrderClient`: python-socketio's client over it (`_engineio_client_class`).
* A WebSocket-first start (`transports=["websocket"]`) that falls back to long-polling when Engine.IO itself
  failed: python-socketio chains that failure as the `__cause__` of its ConnectionError.
"""

from __future__ import annotations

import queue
import select
import ssl
import threading
from collections.abc import Callable
from typing import Any

import engineio
import socketio
import websocket


class OneWayAtATimeWebSocket(websocket.WebSocket):
    """websocket-client's WebSocket that never reads and writes its TLS socket at the same time.

    python-engineio's client reads on one thread and writes on another, and an `ssl.SSLSocket` is not safe for
    that: now and then a message sent while the other thread reads never arrives (an INIT left unanswered, a
    namespace never connected: 1 to 5 connections in 100 here; python-engineio issue #461). Here one lock covers
    reads and writes, and the reader waits for data to arrive before it takes the lock, so a writer waits at most
    for one arriving frame, never for the netapp's next message.
    """

    def connect(self, *args: Any, **kwargs: Any) -> None:
        super().connect(*args, **kwargs)
        if isinstance(self.sock, ssl.SSLSocket):  # a plain socket reads and writes at once safely: two locks
            self.lock = self.readlock = threading.RLock()  # reentrant: a read answers a ping with a pong

    def recv(self) -> str | bytes:
        sock = self.sock
        try:
            if isinstance(sock, ssl.SSLSocket) and not sock.pending():  # nothing decrypted and waiting already
                if not select.select([sock], [], [], sock.gettimeout())[0]:
                    raise websocket.WebSocketTimeoutException("no data from the netapp")
        except (OSError, ValueError, AttributeError):
            pass  # closed meanwhile: recv() says so in its own words
        return super().recv()


# python-engineio hands these to `websocket.create_connection`. websocket-client checks text frames' UTF-8 in pure
# Python (~0.4 ms a result here) before recv() decodes them with bytes.decode("utf-8"), which refuses bad UTF-8 as
# well: the first check is redundant.
WEBSOCKET_OPTIONS: dict[str, Any] = {"skip_utf8_validation": True, "class_": OneWayAtATimeWebSocket}


class InOrderEngineIOClient(engineio.Client):
    """python-engineio's client starts a new thread for every message it receives (`_trigger_event(...,
    run_async=True)`): a thread start per result (measured ~0.3 ms of each result's downlink on a busy 2-core
    machine), and results that may overtake each other. Here one long-lived thread per client takes the messages in
    the order they arrived. A handler must not wait for a later message (an ack): ours hand such waits to threads of
    their own (`SocketIOTransport._on_control_connect`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._messages: queue.SimpleQueue[tuple[Callable[..., Any], tuple] | None] = queue.SimpleQueue()
        self._dispatcher: threading.Thread | None = None
        self._dispatch_lock = threading.Lock()

    def _trigger_event(self, event: str, *args: Any, **kwargs: Any) -> Any:
        if event != "message" or not kwargs.get("run_async") or event not in self.handlers:
            return super()._trigger_event(event, *args, **kwargs)
        with self._dispatch_lock:
            if self._dispatcher is None:
                self._dispatcher = threading.Thread(target=self._dispatch, name="netapp-sio-dispatch", daemon=True)
                self._dispatcher.start()
        self._messages.put((self.handlers[event], args))
        return None

    def _dispatch(self) -> None:
        while (item := self._messages.get()) is not None:
            handler, args = item
            try:
                handler(*args)
            except Exception:
                self.logger.exception("message handler error")

    def disconnect(self, abort: bool = False, reason: Any = None) -> None:
        if self.state == "connected" and self.current_transport == "polling" and not abort:
            # python-engineio's disconnect waits for the read loop, that is for the poll in flight, which the
            # netapp answers only with its next ping (up to 25 s). Post the CLOSE (after the namespaces' packets
            # already queued), wait for that alone, and let the poll's daemon thread end by itself later.
            self._send_packet(engineio.packet.Packet(engineio.packet.CLOSE))
            self.queue.put(None)  # ends the write loop's batch...
            self.queue.put(None)  # ...and the write loop
            self.write_loop_task.join(self.request_timeout)
            abort = True
        super().disconnect(abort=abort, reason=reason)

    def stop_dispatch(self) -> None:
        """End the dispatching thread once the messages before this call are handled."""
        with self._dispatch_lock:
            if self._dispatcher is not None:
                self._messages.put(None)
                self._dispatcher = None


class InOrderClient(socketio.Client):
    """A socketio.Client over InOrderEngineIOClient."""

    def _engineio_client_class(self) -> type[engineio.Client]:
        return InOrderEngineIOClient


def engineio_failed(exc: socketio.exceptions.ConnectionError) -> bool:
    """Whether a failed `connect` was Engine.IO's own (no WebSocket through: a proxy, a balancer), which
    long-polling may pass, rather than a namespace the netapp refused (a token, a draining replica)."""
    return isinstance(exc.__cause__, engineio.exceptions.ConnectionError)


# Everything above relies on beyond the public API, by owner: methods overridden or called, attributes read or set
# on instances, parameters passed. Checked against the installed libraries by
# tests/netapp/client/test_engineio_compat.py.
RELIES_ON: dict[str, dict[str, tuple[str, ...]]] = {
    "engineio.Client": {
        "methods": ("_trigger_event", "_send_packet", "disconnect", "_connect_websocket", "_receive_packet"),
        "instance_attributes": (
            "handlers",
            "state",
            "current_transport",
            "queue",
            "write_loop_task",
            "request_timeout",
            "logger",
            "sid",
            "websocket_extra_options",
        ),
        "parameters:disconnect": ("abort", "reason"),
        "parameters:_send_packet": ("pkt",),
    },
    "socketio.Client": {"methods": ("_engineio_client_class",), "instance_attributes": ("eio",)},
    "websocket.WebSocket": {
        "methods": ("connect", "recv"),
        "instance_attributes": ("sock", "lock", "readlock"),
        "parameters:__init__": ("skip_utf8_validation",),
    },
    "websocket.create_connection": {"parameters": ("class_",)},
}
