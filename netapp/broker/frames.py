"""Frames through a broker (docs/broker.md#frames-through-a-broker), what travels beside each frame (pure).

A frame's body is the `frames` wire's binary message (`netapp.framing.pack_frame`: the one `EncodedFrame`), the same
bytes as on the WebSocket; what the WebSocket knows from its connection travels as the broker's own message
properties: who sent it (`robot`, its results' source), the robot's own session (`session`, its results' key),
where its results go (`reply`: AMQP reply_to, an MQTT 5 response topic, a Kafka topic) and when it is stale
(`expires_ns`, the robot's wall clock plus its deadline: a backlog an outage left is dropped, never answered late).
What comes back is the `frames` wire's text events (`netapp.framing.event`: `results`, `error`), as bytes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from netapp.framing import WireError

ROBOT_HEADER = "robot_id"
SESSION_HEADER = "session"
EXPIRES_HEADER = "expires_ns"
REPLY_HEADER = "reply_to"  # Kafka's (AMQP and MQTT 5 have a property of their own)
MAX_HEADER_CHARS = 128


@dataclass(frozen=True)
class Envelope:
    """What a broker message says about the frame it carries."""

    robot: str
    session: str
    reply: str | None = None
    expires_ns: int | None = None  # wall clock, ns since the epoch; None: never stale

    def stale(self, now_ns: int) -> bool:
        return self.expires_ns is not None and now_ns > self.expires_ns

    def headers(self) -> dict[str, str]:
        """As string headers (AMQP headers, MQTT 5 user properties, Kafka headers)."""
        fields = {ROBOT_HEADER: self.robot, SESSION_HEADER: self.session}
        if self.expires_ns is not None:
            fields[EXPIRES_HEADER] = str(self.expires_ns)
        return fields


def expires_ns(deadline_ms: float | None, now_ns: int) -> int | None:
    """When a frame sent at `now_ns` with `deadline_ms` goes stale (None: no deadline)."""
    return None if not deadline_ms else now_ns + int(deadline_ms * 1e6)


def expiry_s(deadline_ms: float | None) -> int | None:
    """MQTT 5's message expiry interval (whole seconds, at least 1) for `deadline_ms`."""
    return None if not deadline_ms else max(1, math.ceil(deadline_ms / 1000))


def read_envelope(headers: Mapping[str, Any] | None, reply: str | None) -> Envelope:
    """A broker message's headers -> its Envelope; WireError (`bad_envelope`) for what a robot could not have sent:
    no robot or session, a field too long or not text, an expiry that is not a number."""
    headers = headers or {}
    robot, session, expires = (_text(headers.get(name)) for name in (ROBOT_HEADER, SESSION_HEADER, EXPIRES_HEADER))
    if not robot or not session:
        raise WireError("bad_envelope", f"a frame message needs the {ROBOT_HEADER} and {SESSION_HEADER} headers")
    if expires is not None and not expires.isdigit():
        raise WireError("bad_envelope", f"{EXPIRES_HEADER} must be ns since the epoch, got {expires[:32]!r}")
    reply = _text(reply)
    return Envelope(robot, session, reply or None, int(expires) if expires else None)


def _text(value: Any) -> str | None:
    if isinstance(value, bytes):
        try:
            value = value.decode()
        except UnicodeDecodeError:
            raise WireError("bad_envelope", "a header is not UTF-8") from None
    if value is None:
        return None
    if not isinstance(value, str) or len(value) > MAX_HEADER_CHARS:
        raise WireError("bad_envelope", f"a header must be text of at most {MAX_HEADER_CHARS} characters")
    return value
