"""How encoded frames travel to one netapp and results come back: one object per connection, one small protocol.

A transport connects (registers, or connects and INITs), transmits encoded frames and closes; it reports back
through the `TransportCallbacks` the client gives it. It knows nothing of scheduling (the client's in-flight bound
and newest-wins slot) nor of encoding (`netapp.client.encoders`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import requests

from netapp.frame import EncodedFrame
from netapp.protocol import SUPERSEDED_REASON


@dataclass(frozen=True)
class SessionSettings:
    """What a transport needs to open a session with a netapp."""

    robot_id: str | None = None
    args: dict[str, Any] = field(default_factory=dict)
    max_in_flight: int = 2
    connect_timeout_s: float = 10.0
    result_timeout_s: float = 10.0
    # the netapp's bearer token, when it needs one (the middleware gives it with the URL); never in a repr or a log
    token: str | None = field(default=None, repr=False)
    # Socket.IO: open the session on a WebSocket straight away (long-polling first when that fails or when False).
    # One connection per robot, so behind replicas its handshake and frames are on one replica: nothing to forward.
    websocket_first: bool = True

    def auth_headers(self) -> dict[str, str]:
        return bearer_headers(self.token)


def bearer_headers(token: str | None) -> dict[str, str]:
    """The netapp's token as a request header (none without a token)."""
    return {"Authorization": f"Bearer {token}"} if token else {}


@dataclass(frozen=True)
class TransportCallbacks:
    """How a transport reports back, from its own threads; it stops calling them once `close()` has begun."""

    on_ready: Callable[[], None]  # the session is open (again, after a reconnect): frames may be sent
    on_lost: Callable[[], None]  # the connection dropped: frames in flight will get no result
    on_result: Callable[[dict[str, Any]], None]  # a result message
    on_error: Callable[[dict[str, Any]], None]  # an error about a frame (`timestamp`) or the session
    on_dropped: Callable[[int], None]  # the netapp superseded this frame in its queue (newest wins there too)
    on_refused: Callable[[str], None]  # the netapp refused the session: what it said
    on_move: Callable[[str], None]  # the netapp is going away (draining, the reason): open a new session elsewhere
    # What the netapp says of the session as it opens (before `on_ready`): the `/register` answer, or the Socket.IO
    # `session_info` event before INIT's ack (its processor's `input_size`, `docs/server.md#input-size`).
    on_session_info: Callable[[dict[str, Any]], None] = lambda info: None
    # A stateful netapp's session state to restore in a new session before its first frame (None: nothing), and
    # how that went (ok, the netapp's message).
    state_to_restore: Callable[[], Any] = lambda: None
    on_restored: Callable[[bool, str], None] = lambda ok, message: None


def report_error(callbacks: TransportCallbacks, message: Any) -> None:
    """A netapp's error event about a frame or the session -> `on_dropped` for a frame its queue superseded (newest
    wins there too: not an error), `on_error` for the others."""
    message = message if isinstance(message, dict) else {"error": str(message)}
    if message.get("reason") == SUPERSEDED_REASON and isinstance(message.get("timestamp"), int):
        callbacks.on_dropped(message["timestamp"])
    else:
        callbacks.on_error(message)


def environment_settings(url: str) -> tuple[bool | str, dict[str, str]]:
    """Where `requests.get(url)` would look for the certificate bundle and the proxies (REQUESTS_CA_BUNDLE,
    HTTPS_PROXY, ...): (verify, proxies), read once for a transport's own connections to honour them too."""
    env = requests.Session().merge_environment_settings(url, {}, None, None, None)
    return env.get("verify", True), env.get("proxies") or {}


class Transport(Protocol):
    """One connection to one netapp."""

    def connect(self) -> None:
        """Open the session; returns once frames may be sent, raises `NetAppError` when it cannot."""

    def transmit(self, frame: EncodedFrame) -> None:
        """Put one frame on the wire without waiting for its result; raises when it cannot."""

    def close(self) -> None:
        """End the session; no callback runs afterwards."""

    @property
    def session_id(self) -> str | None:
        """The netapp's id of this session, None while there is none."""
