"""The `frames` transport: the toolkit's binary frames on one plain WebSocket (`netapp.framing`, docs/protocol.md).

websockets' sync client (measured against websocket-client: `python -m bench.ws_clients`, docs/decisions.md). The
caller's thread puts a frame on the wire (one message: header, optional JSON part, payload); a reader thread per
connection takes the netapp's text events and reports them through the callbacks. A dropped connection is
reported (`on_lost`); the link connects this transport again (`netapp.client.link`: each `connect()` INITs and
restores the session state, then reports `on_ready`). What the messages mean (command ids, acknowledgements, the
netapp's events, the message bound) is the I/O-free `netapp.frames_session.FramesSession`; this file is only its I/O.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import ssl
import threading
from typing import Any

from websockets.exceptions import ConnectionClosed, InvalidHandshake
from websockets.sync.client import ClientConnection, connect

from netapp.client.errors import ConnectionLost, NetAppError, refusal
from netapp.client.transports import SessionSettings, TransportCallbacks, environment_settings, report_error
from netapp.client.transports.outbox import Outbox
from netapp.frame import EncodedFrame
from netapp.frames_session import Acked, FrameError, FramesSession, Moved, Refused, Results, SessionInfo
from netapp.framing import frames_url
from netapp.protocol import CommandType

log = logging.getLogger(__name__)


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
        self._protocol = FramesSession()  # the current connection's, under `_answered`
        self._answers: dict[int, Acked] = {}  # acknowledgements of the commands the protocol awaits, until taken
        self._answered = threading.Condition()
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
        data = self._protocol.frame(frame)  # the frame's edge: its binary message
        outbox = self._outbox
        if outbox is None or not self._ready:
            raise ConnectionLost("the frames connection is down")
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
        protocol = FramesSession()
        try:
            ws = connect(
                frames_url(self.url),
                additional_headers=self.settings.auth_headers(),
                open_timeout=self.settings.connect_timeout_s,
                ssl=self._ssl,
                **protocol.socket_options(),
            )
        except (OSError, InvalidHandshake, TimeoutError) as exc:
            raise NetAppError(f"cannot connect to {self.url}: {exc}") from exc
        if self._closed.is_set():  # closed while connecting again
            ws.close()
            raise NetAppError(f"the session with {self.url} is closed")
        with self._answered:
            self._protocol, self._answers = protocol, {}
        self._ws, self._ended, self._outbox = ws, threading.Event(), Outbox(ws)
        reader = threading.Thread(target=self._read, args=(ws, self._ended, self._outbox), daemon=True)
        reader.name = "netapp-frames"
        reader.start()
        try:
            settings = self.settings
            data = {**settings.args, **({"robot_id": settings.robot_id} if settings.robot_id else {})}
            answer = self._command(ws, CommandType.INIT, data)
            if not answer.ok:
                refused = refusal(self.url, {"reason": "init_refused", **answer.answer}, answer.message)
                self.callbacks.on_refused(str(refused))
                raise refused
            self._session_id = answer.answer.get("session_id")
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

    def _command(self, ws: ClientConnection, cmd_type: CommandType, data: Any) -> Acked:
        """Send a command and wait for its acknowledgement (a refusal of the connection raises NetAppRefused)."""
        with self._answered:
            protocol = self._protocol
            command = protocol.command(cmd_type, data)
        try:
            ws.send(command.text)
        except ConnectionClosed:
            pass  # a refused connection is closed at once: its `refused` event says why
        timeout = self.settings.connect_timeout_s
        ended, ident = self._ended, command.ident
        with self._answered:
            done = self._answered.wait_for(
                lambda: (
                    ident in self._answers or protocol.refused is not None or ended.is_set() or self._closed.is_set()
                ),
                timeout,
            )
            answer = self._answers.pop(ident, None)
            protocol.abandon(ident)
        if protocol.refused is not None:
            raise refusal(self.url, protocol.refused)
        if answer is None:
            why = "did not acknowledge" if not done else "closed the connection before acknowledging"
            raise NetAppError(f"{self.url} {why} {cmd_type.name} within {timeout} s")
        return answer

    def _restore(self, ws: ClientConnection, state: Any) -> None:
        """SET_STATE before the first frame; a refusal is reported and the session starts from a fresh state."""
        try:
            answer = self._command(ws, CommandType.SET_STATE, state)
            ok, message = answer.ok, str(answer.answer.get("message"))
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
        """A session's connection dropped (once it was ready): report it (the link connects again)."""
        with self._state_lock:
            if self._closed.is_set() or ws is not self._ws or not self._ready:
                return  # closed by us, or still opening (`_open` says why)
            self._ws, self._ready = None, False
        self.callbacks.on_lost()

    def _on_message(self, text: str) -> None:
        with self._answered:
            got = self._protocol.receive(text)
            if isinstance(got, (Acked, Refused)):  # what a command waits for
                if isinstance(got, Acked):
                    self._answers[got.ident] = got
                self._answered.notify_all()
                return
        if self._closed.is_set():
            return
        callbacks = self.callbacks
        if isinstance(got, Results):
            callbacks.on_result(got.data)
        elif isinstance(got, FrameError):
            report_error(callbacks, got.data)
        elif isinstance(got, SessionInfo):
            callbacks.on_session_info(got.data)
        elif isinstance(got, Moved):
            callbacks.on_move(got.reason)


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
