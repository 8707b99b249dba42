"""The W3C trace context (https://www.w3.org/TR/trace-context/) as it travels with a frame or a request (pure, no
OpenTelemetry import, shared by the netapp, the robot client, the middleware and the operator).

Every transport carries the same two fields under the same names: HTTP headers on `POST /send_image` (and on the
middleware's `POST /deployments`), keys of the `metadata` object of a Socket.IO frame message, keys of the JSON part
of a `frames` message (docs/tracing.md). A sender without them (a 5G-ERA robot) is served as before.

What arrives is hostile: a `traceparent` that does not follow the format is ignored, as the recommendation says
(the receiver then decides by its own sampler), and so is a `tracestate` longer than the recommendation's 512
characters; nothing else about the frame changes.
"""

from __future__ import annotations

import random
import re
from dataclasses import dataclass
from typing import Any

TRACEPARENT = "traceparent"  # the HTTP header, and the key in a frame message's metadata
TRACESTATE = "tracestate"
TRACEPARENT_LENGTH = 55  # version 00: "00-" 32 hex "-" 16 hex "-" 2 hex
MAX_TRACESTATE = 512  # the recommendation's limit for what a vendor must propagate
MAX_TRACESTATE_MEMBERS = 32
SAMPLED = 0x01  # the trace-flags bit
# One tracestate list member, `key=value` (the recommendation's grammar: a simple or a multi-tenant key).
_MEMBER = re.compile(
    r"(?:[a-z][_0-9a-z\-*/]{0,255}|[a-z0-9][_0-9a-z\-*/]{0,240}@[a-z][_0-9a-z\-*/]{0,13})"
    r"=[\x20-\x2b\x2d-\x3c\x3e-\x7e]{0,255}[\x21-\x2b\x2d-\x3c\x3e-\x7e]"
)


@dataclass(frozen=True)
class TraceContext:
    """A parent span as a traceparent names it: its trace, its span, whether it was sampled, and the tracestate."""

    trace_id: int
    span_id: int
    sampled: bool
    tracestate: str = ""

    def traceparent(self) -> str:
        return f"00-{self.trace_id:032x}-{self.span_id:016x}-{SAMPLED if self.sampled else 0:02x}"

    def fields(self) -> dict[str, str]:
        """The context as a transport carries it (header names = metadata keys)."""
        fields = {TRACEPARENT: self.traceparent()}
        if self.tracestate:
            fields[TRACESTATE] = self.tracestate
        return fields


def new_trace_id() -> int:
    """A random, valid (non-zero) 128-bit trace id."""
    return random.getrandbits(128) or 1


def new_span_id() -> int:
    """A random, valid (non-zero) 64-bit span id."""
    return random.getrandbits(64) or 1


def _hex(text: str) -> int | None:
    """Lowercase hex only (the recommendation's), as an int; None otherwise."""
    if not text or text.strip("0123456789abcdef"):
        return None
    return int(text, 16)


def parse(traceparent: Any, tracestate: Any = None) -> TraceContext | None:
    """A received traceparent (and tracestate) -> its context; None when absent or malformed (ignored, never an
    error: the W3C recommendation's rule). A version above 00 is read by its first 55 characters."""
    if not isinstance(traceparent, str) or len(traceparent) < TRACEPARENT_LENGTH or len(traceparent) > 512:
        return None
    version = traceparent[:2]
    if version == "ff" or _hex(version) is None:
        return None
    if version == "00" and len(traceparent) != TRACEPARENT_LENGTH:
        return None
    if len(traceparent) > TRACEPARENT_LENGTH and traceparent[TRACEPARENT_LENGTH] != "-":
        return None
    if traceparent[2] != "-" or traceparent[35] != "-" or traceparent[52] != "-":
        return None
    trace_id, span_id, flags = _hex(traceparent[3:35]), _hex(traceparent[36:52]), _hex(traceparent[53:55])
    if not trace_id or not span_id or flags is None:  # all-zero ids are invalid too
        return None
    return TraceContext(trace_id, span_id, bool(flags & SAMPLED), _tracestate(tracestate))


def _tracestate(value: Any) -> str:
    """A received tracestate as it is propagated: '' when absent, too long or not the recommendation's list."""
    if not isinstance(value, str) or not value or len(value) > MAX_TRACESTATE:
        return ""
    members = [m.strip(" \t") for m in value.split(",")]
    members = [m for m in members if m]
    if len(members) > MAX_TRACESTATE_MEMBERS or not all(_MEMBER.fullmatch(m) for m in members):
        return ""
    return ",".join(members)


def from_mapping(fields: Any) -> TraceContext | None:
    """The context in a frame message's `metadata` (Socket.IO) or JSON part (`frames`), if any."""
    if not isinstance(fields, dict):
        return None
    return parse(fields.get(TRACEPARENT), fields.get(TRACESTATE))
