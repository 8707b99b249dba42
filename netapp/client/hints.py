"""What a netapp would like next, as its results (and its session info) say: checked like any input from the network.

A result may carry `"hint": {"input_size": [w, h], "next_frame_in_ms": t}` (`docs/client.md#hints`). Each
value is bounded before the client acts on it: sides are integers in [MIN_SIDE, MAX_SIDE], never more pixels than
the robot's own frame (a larger size is scaled down to it), and `next_frame_in_ms` is finite in [0,
MAX_NEXT_FRAME_MS]. A malformed hint is ignored (the client keeps what it had), counted, and logged once per client.
"""

from __future__ import annotations

import logging
import math
import re
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from netapp.client.stats import ClientStats
from netapp.protocol import HINT_FIELD, INPUT_SIZE_FIELD, NEXT_FRAME_FIELD

log = logging.getLogger(__name__)

T = TypeVar("T")

MIN_SIDE = 32  # the floor: no processor is asked to work on less
MAX_SIDE = 8192
MAX_NEXT_FRAME_MS = 10_000.0
PROFILE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")  # a file name in netapp/profiles, no path

Size = tuple[int, int]  # (width, height)


@dataclass(frozen=True)
class Hint:
    input_size: Size | None = None  # what the netapp's processor consumes, within the robot's frame
    next_frame_in_ms: float | None = None  # when the netapp will take this robot's next frame


def check_input_size(raw: Any, source: Size | None = None) -> Size:
    """`[w, h]` from the network -> (w, h) within bounds and no more pixels than `source`; ValueError saying why
    not."""
    if not isinstance(raw, (list, tuple)) or len(raw) != 2:
        raise ValueError(f"{INPUT_SIZE_FIELD} must be [width, height], got {raw!r:.80}")
    if not all(isinstance(v, int) and not isinstance(v, bool) and MIN_SIDE <= v <= MAX_SIDE for v in raw):
        raise ValueError(f"{INPUT_SIZE_FIELD} sides must be integers in [{MIN_SIDE}, {MAX_SIDE}], got {raw!r:.80}")
    width, height = raw
    if source is not None and width * height > source[0] * source[1]:
        shrink = math.sqrt(source[0] * source[1] / (width * height))  # the same shape, the source's pixel count
        width, height = max(MIN_SIDE, int(width * shrink)), max(MIN_SIDE, int(height * shrink))
    return width, height


def check_hint(raw: Any, source: Size | None = None) -> Hint:
    """A result's `hint` object -> a bounded `Hint`; ValueError saying what is wrong with it."""
    if not isinstance(raw, dict):
        raise ValueError(f"{HINT_FIELD} must be an object, got {type(raw).__name__}")
    size = raw.get(INPUT_SIZE_FIELD)
    next_ms = raw.get(NEXT_FRAME_FIELD)
    if next_ms is not None and (
        isinstance(next_ms, bool)
        or not isinstance(next_ms, (int, float))
        or not math.isfinite(next_ms)
        or not 0 <= next_ms <= MAX_NEXT_FRAME_MS
    ):
        raise ValueError(f"{NEXT_FRAME_FIELD} must be a number in [0, {MAX_NEXT_FRAME_MS:g}], got {next_ms!r:.80}")
    return Hint(None if size is None else check_input_size(size, source), None if next_ms is None else float(next_ms))


def check_profile_name(raw: Any) -> str:
    """An accuracy profile's name from the network: a plain file name in netapp/profiles, never a path."""
    if isinstance(raw, str) and PROFILE_NAME.fullmatch(raw):
        return raw
    raise ValueError(f"accuracy_profile must be a profile's name, got {str(raw)[:80]!r}")


def parse_hint(raw: Any, source: Size | None = None) -> Hint | None:
    """The bounded hint, or None for none or a malformed one (pure; `HintReader` counts and logs)."""
    if raw is None:
        return None
    try:
        return check_hint(raw, source)
    except ValueError:
        return None


class HintReader:
    """A client's reader of hints from every netapp: a malformed one is counted (`stats.bad_hints`) and the first
    one logged, so a misbehaving netapp costs one log line, not one per result."""

    def __init__(self, stats: ClientStats) -> None:
        self._stats = stats
        self._lock = threading.Lock()
        self._logged = False

    def read(self, raw: Any, source: Size | None, url: str) -> Hint | None:
        return self._checked(lambda: check_hint(raw, source), raw, url)

    def read_input_size(self, raw: Any, url: str) -> Size | None:
        """The `input_size` of a session's info (the register answer, Socket.IO `session_info`)."""
        return self._checked(lambda: check_input_size(raw), raw, url)

    def read_profile_name(self, raw: Any, url: str) -> str | None:
        """The `accuracy_profile` of a session's info: a profile's name (never a path), or None."""
        return self._checked(lambda: check_profile_name(raw), raw, url)

    def _checked(self, check: Callable[[], T], raw: Any, url: str) -> T | None:
        """What `check` makes of `raw`; None when the netapp said nothing, or said something bad (counted, logged)."""
        if raw is None:
            return None
        try:
            return check()
        except ValueError as exc:
            self.bad(exc, url)
            return None

    def bad(self, exc: ValueError, url: str) -> None:
        self._stats.add(bad_hints=1)
        with self._lock:
            first, self._logged = not self._logged, True
        if first:
            log.warning("ignoring a malformed hint from %s (further ones are only counted): %s", url, exc)
