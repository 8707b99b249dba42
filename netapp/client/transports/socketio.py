"""The Socket.IO transport (5G-ERA): connect to /data and /control, INIT, emit frames, get results as events.

A dropped connection is reported (`on_lost`) and the link connects this transport again (`netapp.client.link`, the
one reconnect policy; python-socketio's own reconnecting is off); every connection INITs again. What it needs
of python-engineio's internals is in `engineio_compat`.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import requests
import socketio
from socketio.packet import Packet

from netapp import wire_json
from netapp.client.errors import ConnectionLost, NetAppError, NetAppRefused, refusal, response_refusal
from netapp.client.transports import SessionSettings, TransportCallbacks, environment_settings, report_error
from netapp.client.transports.engineio_compat import WEBSOCKET_OPTIONS, InOrderClient, engineio_failed
from netapp.frame import H264, JPEG, EncodedFrame
from netapp.protocol import (
    COMMAND_ERROR_EVENT,
    COMMAND_EVENT,
    CONTROL_NAMESPACE,
    DATA_ERROR_EVENT,
    DATA_NAMESPACE,
    DEADLINE_FIELD,
    H264_EVENT,
    IMAGE_EVENT,
    MOVE_EVENT,
    RESULTS_EVENT,
    SESSION_INFO_EVENT,
    CommandType,
)

log = logging.getLogger(__name__)

EVENTS = {JPEG: IMAGE_EVENT, H264: H264_EVENT}  # the data event that carries each codec


def era_message(frame: EncodedFrame) -> dict[str, Any]:
    """The frame's edge on Socket.IO: 5G-ERA's data message (`timestamp`, `frame`; H.264: the picture's `width` and
    `height`), with the toolkit's `deadline_ms` and `metadata` when it has them."""
    message: dict[str, Any] = {"timestamp": frame.timestamp, "frame": frame.payload}
    if frame.codec == H264:
        message.update(width=frame.width, height=frame.height)
    if frame.deadline_ms is not None:
        message[DEADLINE_FIELD] = frame.deadline_ms
    if frame.meta:
        message["metadata"] = frame.meta
    return message


class WirePacket(Packet):
    """python-socketio's packet with its JSON by `netapp.wire_json` (a subclass: the robot's own Socket.IO clients, if
    any, keep theirs)."""

    json = wire_json


class SocketIOTransport:
    """A Socket.IO session with one netapp."""

    def __init__(self, url: str, settings: SessionSettings, callbacks: TransportCallbacks) -> None:
        self.url = url
        self.settings = settings
        self.callbacks = callbacks
        self._ready = threading.Event()
        self._answered = threading.Event()  # INIT acknowledged, either way
        self._refusal: NetAppRefused | None = None  # how the netapp refused INIT
        self._command_error: dict[str, Any] = {}  # the latest command_error: it comes just before its ack
        self._closed = False
        # The certificate bundle and proxies `requests` would use for this URL, for the WebSocket as well as for
        # long-polling: python-engineio reads both from its HTTP session (REQUESTS_CA_BUNDLE then serves wss://).
        http = requests.Session()
        http.verify, proxies = environment_settings(url)
        http.proxies.update(proxies)
        self._http = http
        self._sio = InOrderClient(
            http_session=http,
            reconnection=False,  # the link reconnects, as for every transport
            handle_sigint=False,
            websocket_extra_options=dict(WEBSOCKET_OPTIONS),
            serializer=WirePacket,
        )
        self._sio.on(RESULTS_EVENT, self._on_result, namespace=DATA_NAMESPACE)
        self._sio.on(DATA_ERROR_EVENT, self._on_error, namespace=DATA_NAMESPACE)
        self._sio.on("connect", self._on_control_connect, namespace=CONTROL_NAMESPACE)
        self._sio.on("disconnect", self._on_disconnect, namespace=CONTROL_NAMESPACE)
        self._sio.on(MOVE_EVENT, self._on_move, namespace=CONTROL_NAMESPACE)
        self._sio.on(COMMAND_ERROR_EVENT, self._on_command_error, namespace=CONTROL_NAMESPACE)
        self._sio.on(SESSION_INFO_EVENT, self._on_session_info, namespace=CONTROL_NAMESPACE)
        self._refused: str | None = None  # why the netapp refused the connection (e.g. no or a wrong token)
        self._refused_fields: dict[str, Any] = {}  # and its machine-readable part (`reason`)
        self._sio.on("connect_error", self._on_connect_error, namespace=CONTROL_NAMESPACE)

    @property
    def session_id(self) -> str | None:
        return self._sio.eio.sid

    def connect(self) -> None:
        if self._closed:
            raise NetAppError(f"the session with {self.url} is closed")
        self._answered.clear()  # a connection again after a drop: this one's INIT
        self._refusal, self._refused, self._refused_fields = None, None, {}
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
                if self._refused_fields.get("reason"):
                    raise refusal(self.url, self._refused_fields, self._refused or "") from exc
                if transports is None or not engineio_failed(exc):  # long-polling will not pass either
                    raise self._refusal_at_handshake() or NetAppError(
                        f"cannot connect to {self.url}: {self._refused or exc}"
                    ) from exc
                log.info("no WebSocket to %s (%s): starting with long-polling", self.url, exc)
                self._refused = None
        if not self._answered.wait(timeout):
            raise NetAppError(f"{self.url} did not acknowledge INIT within {timeout} s")
        if self._refusal is not None:
            raise self._refusal

    def _refusal_at_handshake(self) -> NetAppRefused | None:
        """Why the Engine.IO handshake failed, when the netapp refuses robots (a draining replica answers it with a
        bare 503 or WebSocket close 1013): its readiness says so in an error body, with Retry-After."""
        try:
            return response_refusal(self.url, self._http.get(f"{self.url}/readyz", timeout=2))
        except requests.RequestException:
            return None

    def transmit(self, frame: EncodedFrame) -> None:
        event = EVENTS.get(frame.codec)
        if event is None:
            raise ValueError(f"the Socket.IO transport carries {sorted(EVENTS)} frames, not {frame.codec}")
        try:
            self._sio.emit(event, era_message(frame), namespace=DATA_NAMESPACE)
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
        fields = data.get("data") if isinstance(data, dict) else None
        self._refused_fields = fields if isinstance(fields, dict) else {}

    def _on_command_error(self, message: Any = None) -> None:
        self._command_error = message if isinstance(message, dict) else {}

    def _on_session_info(self, message: Any = None) -> None:
        # Just before INIT's ack (handled in order), so the link knows the processor's size before its first frame.
        if isinstance(message, dict) and not self._closed:
            self.callbacks.on_session_info(message)

    def _on_result(self, message: Any) -> None:
        if isinstance(message, dict) and not self._closed:
            self.callbacks.on_result(message)

    def _on_error(self, message: Any) -> None:
        if not self._closed:
            report_error(self.callbacks, message)

    def _on_move(self, message: Any = None) -> None:
        if not self._closed:
            reason = message.get("reason") if isinstance(message, dict) else None
            self.callbacks.on_move(str(reason or "move"))

    def _on_control_connect(self) -> None:
        # INIT waits for its ack, which arrives on the thread that runs this handler: send it from another thread.
        threading.Thread(target=self._init_session, name="netapp-init", daemon=True).start()

    def _init_session(self) -> None:
        settings = self.settings
        self._command_error = {}
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
            # The command_error before this ack (Engine.IO messages are handled in order) says why, for a program;
            # the ack keeps 5G-ERA's (ok, message).
            fields = {"reason": "init_refused", **self._command_error}
            self._refusal = refusal(self.url, fields, str(message))
            log.debug("%s: %s", self._refusal, message)
            self.callbacks.on_refused(str(self._refusal))
            self._answered.set()
            return
        state = self.callbacks.state_to_restore()
        if state is not None:
            self._restore(state)
        self._refusal = None
        self.callbacks.on_ready()
        self._ready.set()
        self._answered.set()

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
