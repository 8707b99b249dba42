"""The `frames` transport: the toolkit's binary frames on one plain WebSocket (`netapp.framing`, docs/protocol.md).

websockets' sync client (measured against websocket-client: `python -m bench.ws_clients`, docs/decisions.md). The
caller's thread puts a frame on the wire (one message: header, optional JSON part, payload); a reader thread per
connection takes the netapp's text events and reports them through the callbacks. After a dropped connection it
connects again (0.5 s, then twice as long each time up to 5 s, as python-socketio does for the Socket.IO transport),
INITs, restores the session state, and reports `on_lost` / `on_ready`.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import socket
import ssl
import threading
from typing import Any

from websockets.exceptions import ConnectionClosed, InvalidHandshake
from websockets.sync.client import ClientConnection, connect

from netapp import wire_json
from netapp.client.encoders import EncodedFrame
from netapp.client.errors import ConnectionLost, NetAppError, NetAppRefused, refusal
from netapp.client.transports import SessionSettings, TransportCallbacks, environment_settings, report_error
from netapp.client.transports.outbox import Outbox
from netapp.frame import EncodedFrame as WireFrame
from netapp.framing import ACK_EVENT, CODECS, ERROR_EVENT, REFUSED_EVENT, frames_url, pack_frame
from netapp.protocol import (
    DEADLINE_FIELD,
    MOVE_EVENT,
    RESULTS_EVENT,
    SESSION_INFO_EVENT,
    CommandType,
)

log = logging.getLogger(__name__)

RECONNECT_FIRST_S = 0.5
RECONNECT_MAX_S = 5.0
CLOSE_TIMEOUT_S = 1.0  # closing waits this long for the netapp's close frame
# What the netapp may send us in one message (a result, a GET_STATE answer): past it the connection is closed.
MAX_MESSAGE_BYTES = 16 * 1024 * 1024


class FramesTransport:
    """A frames session with one netapp."""

    def __init__(self, url: str, settings: SessionSettings, callbacks: TransportCallbacks) -> None:
        self.url = url
        self.settings = settings
        self.callbacks = callbacks
        self._ws: ClientConnection | None = None
        self._ready = False
        self._closed = threading.Event()
        self._session_id: str | None = None
        self._ids = itertools.count(1)
        self._answers: dict[int, dict[str, Any]] = {}  # acknowledgements of the commands in `_waiting` only
        self._waiting: set[int] = set()  # ids of commands waiting for their acknowledgement
        self._answered = threading.Condition()
        self._refused: dict[str, Any] | None = None  # the netapp's `refused` event on this connection
        self._ended = threading.Event()  # the current connection's reader has stopped
        self._state_lock = threading.Lock()  # `_ws` and `_ready` change together
        self._outbox: Outbox | None = None  # the current connection's frames out
        verify, _ = environment_settings(url)  # websockets reads the proxies from the environment itself
        self._ssl = _ssl_context(verify) if url.startswith("https") else None

    @property
    def session_id(self) -> str | None:
        return self._session_id

    def connect(self) -> None:
        self._open()

    def transmit(self, frame: EncodedFrame) -> None:
        if frame.codec not in CODECS:
            raise ValueError(f"the frames transport carries {sorted(CODECS)} frames, not {frame.codec}")
        outbox = self._outbox
        if outbox is None or not self._ready:
            raise ConnectionLost("the frames connection is down")
        message = frame.message
        data = pack_frame(
            WireFrame(
                frame.codec,
                message["timestamp"],
                message["frame"],
                width=message.get("width") or 0,
                height=message.get("height") or 0,
                deadline_ms=message.get(DEADLINE_FIELD),
                meta=message.get("metadata"),
            )
        )
        try:
            outbox.send(data)  # never waits on the link (`outbox`)
        except ConnectionClosed as exc:  # dropped, and not yet reported by on_lost
            raise ConnectionLost(str(exc)) from exc

    def close(self) -> None:
        self._closed.set()
        self._ready = False
        ws, self._ws = self._ws, None
        outbox = self._outbox
        if ws is not None:
            if outbox is not None and outbox.close():  # a frame stuck on a link that takes nothing: cut it off,
                with contextlib.suppress(OSError):  # or closing would wait for it (it holds the connection's lock)
                    ws.socket.shutdown(socket.SHUT_RDWR)
            ws.close()
        with self._answered:
            self._answered.notify_all()

    # -- opening a session --------------------------------------------------------------------------------------

    def _open(self) -> None:
        """Connect, INIT and restore the state; NetAppError (NetAppRefused when the netapp said no) else."""
        timeout = self.settings.connect_timeout_s
        try:
            ws = connect(
                frames_url(self.url),
                additional_headers=self.settings.auth_headers(),
                open_timeout=timeout,
                close_timeout=CLOSE_TIMEOUT_S,
                compression=None,  # JPEG and H.264 do not compress: deflate would only cost CPU
                max_size=MAX_MESSAGE_BYTES,
                ssl=self._ssl,
            )
        except (OSError, InvalidHandshake, TimeoutError) as exc:
            raise NetAppError(f"cannot connect to {self.url}: {exc}") from exc
        self._refused = None
        self._ws, self._ended, self._outbox = ws, threading.Event(), Outbox(ws)
        reader = threading.Thread(target=self._read, args=(ws, self._ended, self._outbox), daemon=True)
        reader.name = "netapp-frames"
        reader.start()
        try:
            settings = self.settings
            data = {**settings.args, **({"robot_id": settings.robot_id} if settings.robot_id else {})}
            answer = self._command(ws, CommandType.INIT, data)
            if not answer.get("ok"):
                fields = {"reason": "init_refused", **answer}
                refused = refusal(self.url, fields, str(answer.get("message") or ""))
                self.callbacks.on_refused(str(refused))
                raise refused
            self._session_id = answer.get("session_id")
            state = self.callbacks.state_to_restore()
            if state is not None:
                self._restore(ws, state)
        except BaseException:
            with self._state_lock:
                self._ws = None
            ws.close()
            raise
        with self._state_lock:
            self._ready = True
        self.callbacks.on_ready()
        if self._ended.is_set():  # it dropped as it opened: its reader has gone
            self._dropped(ws)

    def _command(self, ws: ClientConnection, cmd_type: CommandType, data: Any) -> dict[str, Any]:
        """Send a command and wait for its acknowledgement (a refusal of the connection raises NetAppRefused)."""
        ident = next(self._ids)
        command = {"id": ident, "cmd_type": int(cmd_type), "clear_queue": False, "data": data}
        with self._answered:
            self._waiting.add(ident)
        try:
            ws.send(wire_json.dumps(command))
        except ConnectionClosed:
            pass  # a refused connection is closed at once: its `refused` event says why
        timeout = self.settings.connect_timeout_s
        ended = self._ended
        with self._answered:
            done = self._answered.wait_for(
                lambda: ident in self._answers or self._refused is not None or ended.is_set() or self._closed.is_set(),
                timeout,
            )
            answer = self._answers.pop(ident, None)
            self._waiting.discard(ident)
        if self._refused is not None:
            raise refusal(self.url, self._refused)
        if answer is None:
            why = "did not acknowledge" if not done else "closed the connection before acknowledging"
            raise NetAppError(f"{self.url} {why} {cmd_type.name} within {timeout} s")
        return answer

    def _restore(self, ws: ClientConnection, state: Any) -> None:
        """SET_STATE before the first frame; a refusal is reported and the session starts from a fresh state."""
        try:
            answer = self._command(ws, CommandType.SET_STATE, state)
            ok, message = bool(answer.get("ok")), str(answer.get("message"))
        except NetAppError as exc:
            ok, message = False, f"SET_STATE failed: {exc}"
        if not ok:
            log.warning("the netapp did not take the session state: %s", message)
        self.callbacks.on_restored(ok, message)

    # -- what comes back ------------------------------------------------------------------------------------------

    def _read(self, ws: ClientConnection, ended: threading.Event, outbox: Outbox) -> None:
        """The connection's reader: its events, then, if it dropped, reconnecting."""
        try:
            for text in ws:
                if not isinstance(text, str):
                    continue  # the netapp sends text only
                try:
                    self._on_message(text)
                except Exception:  # a bug in what handles it: said, and the session's reader goes on
                    log.exception("handling a message from %s failed", self.url)
        except ConnectionClosed:
            pass
        finally:
            with self._answered:
                ended.set()
                self._answered.notify_all()
            outbox.close()
        self._dropped(ws)

    def _dropped(self, ws: ClientConnection) -> None:
        """A session's connection dropped (once it was ready): report it and connect again."""
        with self._state_lock:
            if self._closed.is_set() or ws is not self._ws or not self._ready:
                return  # closed by us, or still opening (`_open` says why)
            self._ws, self._ready = None, False
        self.callbacks.on_lost()
        self._reconnect()

    def _on_message(self, text: str) -> None:
        try:
            message = wire_json.loads(text)
            name = message.get("event")
        except (ValueError, AttributeError):
            log.warning("the netapp sent a message that is no event: %.80s", text)
            return
        data = message.get("data")
        if name == ACK_EVENT:
            with self._answered:
                ident = message.get("id")
                if isinstance(ident, int) and ident in self._waiting:  # else stale or made up: kept, it would pile up
                    self._answers[ident] = message
                    self._answered.notify_all()
        elif self._closed.is_set():
            return
        elif name == RESULTS_EVENT and isinstance(data, dict):
            self.callbacks.on_result(data)
        elif name == ERROR_EVENT:
            report_error(self.callbacks, data)
        elif name == SESSION_INFO_EVENT and isinstance(data, dict):
            self.callbacks.on_session_info(data)
        elif name == MOVE_EVENT:
            reason = data.get("reason") if isinstance(data, dict) else None
            self.callbacks.on_move(str(reason or "move"))
        elif name == REFUSED_EVENT:
            with self._answered:
                self._refused = data if isinstance(data, dict) else {"error": str(data)}
                self._answered.notify_all()

    def _reconnect(self) -> None:
        wait_s = RECONNECT_FIRST_S
        while not self._closed.wait(wait_s):
            try:
                self._open()
                return
            except NetAppRefused as exc:
                log.info("reconnecting to %s: %s", self.url, exc)
                wait_s = exc.retry_after_s or min(2 * wait_s, RECONNECT_MAX_S)
            except NetAppError as exc:
                log.debug("reconnecting to %s: %s", self.url, exc)
                wait_s = min(2 * wait_s, RECONNECT_MAX_S)


def _ssl_context(verify: bool | str) -> ssl.SSLContext:
    """The TLS context `requests` would use for the URL (REQUESTS_CA_BUNDLE and the like)."""
    if verify is False:
        context = ssl.create_default_context()
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
        return context
    if isinstance(verify, str) and os.path.isdir(verify):  # REQUESTS_CA_BUNDLE may name a folder of certificates
        return ssl.create_default_context(capath=verify)
    return ssl.create_default_context(cafile=verify if isinstance(verify, str) else None)
