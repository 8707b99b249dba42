"""A result's hint about the next frame (`netapp.protocol.HINT_FIELD`), read with bounds: it comes from the network."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from netapp.protocol import HINT_FIELD

MAX_NEXT_FRAME_IN_MS = 10_000.0  # a hint further off than this is taken as none


@dataclass(frozen=True)
class Hint:
    next_frame_in_ms: float | None = None  # the netapp takes the robot's next frame this long after the result left


def parse_hint(message: dict[str, Any]) -> Hint | None:
    """The hint of a result message; None without one. A field that is missing, not a number or out of bounds is
    left out (None), never an error: a result is worth more than its hint."""
    raw = message.get(HINT_FIELD)
    if not isinstance(raw, dict):
        return None
    value = raw.get("next_frame_in_ms")
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return Hint(next_frame_in_ms=float(value) if ok and 0 <= value <= MAX_NEXT_FRAME_IN_MS else None)
