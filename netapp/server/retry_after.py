"""When a robot refused for load should try again (the Retry-After of a 503, `retry_after_s` of a Socket.IO
`command_error`, the seconds in a 5G-ERA INIT refusal), from what the netapp measures. Pure: the caller supplies
every number.

- Too many requests waiting for their results: the time the netapp needs to work through the frames waiting now,
  at its measured capacity (`netapp.server.capacity`).
- Sessions full: when the next session is expected to end. Robots come and go independently, each session lasting
  about the mean of those that ended here, so the first of `live` sessions ends in about that mean over `live`.

Each is whole seconds within `MIN_RETRY_AFTER_S`..`MAX_RETRY_AFTER_S`: sooner would be refused again, later than the
bound a robot would rather ask the middleware for another netapp (a client waits no longer than it either).
"""

from __future__ import annotations

import math

from netapp.protocol import MAX_RETRY_AFTER_S

MIN_RETRY_AFTER_S = 1  # Retry-After is whole seconds, and 0 asks for a retry the same load would refuse
SESSIONS_FULL_RETRY_S = 5  # sessions full before any session ended here: nothing measured to go by yet


def bounded(seconds: float) -> int:
    """`seconds` rounded up to whole seconds within the bounds (an unknown time: the longest)."""
    if math.isnan(seconds):
        return MAX_RETRY_AFTER_S
    return int(min(MAX_RETRY_AFTER_S, max(MIN_RETRY_AFTER_S, math.ceil(min(seconds, MAX_RETRY_AFTER_S)))))


def queue_retry_after_s(frames_waiting: int, capacity_fps: float | None) -> int:
    """A request refused because too many wait: the seconds the netapp needs for the `frames_waiting` ahead of it at
    `capacity_fps` results per second (not measured yet: the shortest, as before any measure)."""
    if capacity_fps is None or not capacity_fps > 0:
        return MIN_RETRY_AFTER_S
    return bounded(max(0, frames_waiting) / capacity_fps)


def sessions_retry_after_s(live: int, mean_lifetime_s: float | None) -> int:
    """A robot refused because `live` sessions fill the netapp: when the first of them is expected to end, sessions
    lasting `mean_lifetime_s` on average (None before any ended: `SESSIONS_FULL_RETRY_S`)."""
    if mean_lifetime_s is None or not mean_lifetime_s >= 0:
        return SESSIONS_FULL_RETRY_S
    return bounded(mean_lifetime_s / max(1, live))
