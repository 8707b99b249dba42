"""The Socket.IO transport (5G-ERA): connect to /data and /control, INIT, emit frames, get results as events.

python-socketio reconnects by itself after a dropped connection; every (re)connection INITs again.
"""

from __future__ import annotations

import logging
import queue
import select
import ssl
import threading
from collections.abc import Callable
from typing import Any

import engineio
import requests
import socketio
import websocket

from netapp.client.encoders import EncodedFrame
from netapp.client.errors import ConnectionLost, NetAppError
from netapp.client.transports import SessionSettings, TransportCallbacks, environment_settings
from netapp.protocol import (
    COMMAND_EVENT,
    CONTROL_NAMESPACE,
    DATA_ERROR_EVENT,
    DATA_NAMESPACE,
    H264_EVENT,
    IMAGE_EVENT,
    MOVE_EVENT,
    RESULTS_EVENT,
    SUPERSEDED_REASON,
    CommandType,
)

log = logging.getLogger(__name__)

EVENTS = {"jpeg": IMAGE_EVENT, "h264": H264_EVENT}  # the data event that carries each codec


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


class InOrderEngineIOClient(engineio.Client):
    """python-engineio's client starts a new thread for every message it receives (`_trigger_event(...,
    run_async=True)`): a thread start per result (measured ~0.3 ms of each result's downlink on a busy 2-core
    machine, docs/benchmarks.md#profile), and results that may overtake each other. Here one long-lived thread per
    client takes the messages in the order they arrived. A handler must not wait for a later message (an ack):
    ours hand such waits to threads of their own (`SocketIOTransport._on_control_connect`)."""

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


class SocketIOTransport:
    """A Socket.IO session with one netapp."""

    def __init__(self, url: str, settings: SessionSettings, callbacks: TransportCallbacks) -> None:
        self.url = url
        self.settings = settings
        self.callbacks = callbacks
        self._ready = threading.Event()
        self._closed = False
        # The certificate bundle and proxies `requests` would use for this URL, for the WebSocket as well as for
        # long-polling: python-engineio reads both from its HTTP session (REQUESTS_CA_BUNDLE then serves wss://).
        http = requests.Session()
        http.verify, proxies = environment_settings(url)
        http.proxies.update(proxies)
        self._sio = InOrderClient(
            http_session=http,
            reconnection=True,
            reconnection_attempts=0,
            reconnection_delay=0.5,
            reconnection_delay_max=5,
            handle_sigint=False,
            # websocket-client checks text frames' UTF-8 in pure Python (~0.4 ms a result here) before recv()
            # decodes them with bytes.decode("utf-8"), which refuses bad UTF-8 as well: the first check is redundant.
            websocket_extra_options={"skip_utf8_validation": True, "class_": OneWayAtATimeWebSocket},
        )
        self._sio.on(RESULTS_EVENT, self._on_result, namespace=DATA_NAMESPACE)
        self._sio.on(DATA_ERROR_EVENT, self._on_error, namespace=DATA_NAMESPACE)
        self._sio.on("connect", self._on_control_connect, namespace=CONTROL_NAMESPACE)
        self._sio.on("disconnect", self._on_disconnect, namespace=CONTROL_NAMESPACE)
        self._sio.on(MOVE_EVENT, self._on_move, namespace=CONTROL_NAMESPACE)
        self._refused: str | None = None  # why the netapp refused the connection (e.g. no or a wrong token)
        self._sio.on("connect_error", self._on_connect_error, namespace=CONTROL_NAMESPACE)

    @property
    def session_id(self) -> str | None:
        return self._sio.eio.sid

    def connect(self) -> None:
        timeout = self.settings.connect_timeout_s
        auth = {"token": self.settings.token} if self.settings.token else None
        # None: python-socketio's default, long-polling first and then an upgrade to WebSocket where the way allows
        starts: list[list[str] | None] = [["websocket"], None] if self.settings.websocket_first else [None]
        for transports in starts:
            try:
                self._sio.connect(
                    self.url,
                    namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE],
                    transports=transports,
                    wait_timeout=timeout,
                    auth=auth,
                )
                break
            except socketio.exceptions.ConnectionError as exc:
                # Engine.IO's own failure (no WebSocket through: a proxy, a balancer) may pass with long-polling;
                # a namespace the netapp refused (a token, a draining replica) will not.
                no_websocket = transports is not None and isinstance(exc.__cause__, engineio.exceptions.ConnectionError)
                if not no_websocket:
                    raise NetAppError(f"cannot connect to {self.url}: {self._refused or exc}") from exc
                log.info("no WebSocket to %s (%s): starting with long-polling", self.url, exc)
                self._refused = None
        if not self._ready.wait(timeout):
            raise NetAppError(f"{self.url} did not acknowledge INIT within {timeout} s")

    def transmit(self, frame: EncodedFrame) -> None:
        event = EVENTS.get(frame.codec)
        if event is None:
            raise ValueError(f"the Socket.IO transport carries {sorted(EVENTS)} frames, not {frame.codec}")
        try:
            self._sio.emit(event, frame.message, namespace=DATA_NAMESPACE)
        except socketio.exceptions.BadNamespaceError as exc:  # dropped, and not yet reported by on_lost
            raise ConnectionLost(str(exc)) from exc

    def close(self) -> None:
        self._closed = True
        self._ready.clear()
        try:
            self._sio.disconnect()
        except Exception:
            pass
        self._sio.eio.stop_dispatch()

    def _on_connect_error(self, data: Any = None) -> None:
        message = data.get("message") if isinstance(data, dict) else data
        self._refused = str(message) if message else None

    def _on_result(self, message: Any) -> None:
        if isinstance(message, dict) and not self._closed:
            self.callbacks.on_result(message)

    def _on_error(self, message: Any) -> None:
        if self._closed:
            return
        message = message if isinstance(message, dict) else {"error": str(message)}
        if message.get("reason") == SUPERSEDED_REASON and isinstance(message.get("timestamp"), int):
            self.callbacks.on_dropped(message["timestamp"])  # newest wins on the netapp too: not an error
        else:
            self.callbacks.on_error(message)

    def _on_move(self, message: Any = None) -> None:
        if not self._closed:
            reason = message.get("reason") if isinstance(message, dict) else None
            self.callbacks.on_move(str(reason or "move"))

    def _on_control_connect(self) -> None:
        # INIT waits for its ack, which arrives on the thread that runs this handler: send it from another thread.
        threading.Thread(target=self._init_session, name="netapp-init", daemon=True).start()

    def _init_session(self) -> None:
        settings = self.settings
        command = {
            "cmd_type": int(CommandType.INIT),
            "clear_queue": False,
            "data": {**settings.args, **({"robot_id": settings.robot_id} if settings.robot_id else {})},
        }
        try:
            ok, message = self._sio.call(
                COMMAND_EVENT, command, namespace=CONTROL_NAMESPACE, timeout=settings.connect_timeout_s
            )
        except Exception as exc:
            log.warning("INIT failed: %s", exc)
            return
        if self._closed:
            return
        if not ok:
            log.error("the netapp refused INIT: %s", message)
            self.callbacks.on_refused(f"INIT refused: {message}")
            return
        state = self.callbacks.state_to_restore()
        if state is not None:
            self._restore(state)
        self.callbacks.on_ready()
        self._ready.set()

    def _restore(self, state: Any) -> None:
        """SET_STATE before the first frame; a refusal is reported and the session starts from a fresh state."""
        command = {"cmd_type": int(CommandType.SET_STATE), "clear_queue": False, "data": state}
        try:
            ok, message = self._sio.call(
                COMMAND_EVENT, command, namespace=CONTROL_NAMESPACE, timeout=self.settings.connect_timeout_s
            )
        except Exception as exc:
            ok, message = False, f"SET_STATE failed: {exc}"
        if not ok:
            log.warning("the netapp did not take the session state: %s", message)
        self.callbacks.on_restored(bool(ok), str(message))

    def _on_disconnect(self, *reason: Any) -> None:
        self._ready.clear()
        if not self._closed:
            self.callbacks.on_lost()
