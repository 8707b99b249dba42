"""Whether the robot's next frame goes now (pure): the frames already on the uplink first.

A frame sent behind others on a thin uplink waits for them: where the link just fell (4 to 0.25 Mbit/s), the frames
sent before the robot knew take a second to drain, and every frame sent meanwhile is late too, its result answered
in vain, and the frame after it later still. So a frame goes only where

* it can make the latency budget behind the frames in flight: the uplink is free when the last result's frame left
  it (its network part's end less the round trip) plus the bytes of each frame in flight since at the estimated rate;
  the frame's own bytes at that rate, the round trip and the netapp's time after that must be within the budget
  (it is dropped, not queued: a newer frame follows within a frame's period). Only the queue ahead refuses a frame:
  one that would be late on an empty uplink goes, or nothing would be learnt;
* no frame goes while one in flight is overdue (older than the latency predicted for it when it went, by more than
  `OVERDUE_MS`): the link may have fallen, and a frame sent now would queue behind it before its late result can
  say so (at 4 Mbit/s a 16.6 KB frame takes 33 ms, at 0.25 530 ms: two of them drain in over a second). The frame
  waits for that result (the sender's `in_flight_cap`, as it waits for the pacer's window) rather than being
  dropped: where the result was only a little late, the next frame goes a few milliseconds later, its result not
  lost; where the link fell, it goes with the choice that result made.

Frames in flight longer than `STALE_BUDGETS` budgets are taken as lost (their miss comes later, or never).
"""

from __future__ import annotations

from collections.abc import Sequence

STALE_BUDGETS = 10.0
OVERDUE_MS = 8.0  # a result this much later than predicted: more than the 5G link's jitter (+-4 ms a way)


def overdue(t_s: float, in_flight: Sequence[tuple[float, float]], budget_ms: float) -> bool:
    """Whether a frame in flight ((sent at, its predicted latency in ms)) is overdue at `t_s` (see the module)."""
    stale_s = STALE_BUDGETS * budget_ms / 1000.0
    return any(stale_s >= t_s - sent_s > (predicted_ms + OVERDUE_MS) / 1000.0 for sent_s, predicted_ms in in_flight)


def predicted_latency_ms(
    t_s: float,
    in_flight: Sequence[tuple[float, int]],
    frame_bytes: float,
    rate_bytes_per_ms: float,
    link_free_s: float,
    round_trip_ms: float,
    netapp_ms: float,
) -> float:
    """A frame of `frame_bytes` sent at `t_s`: its latency behind `in_flight` ((sent at, bytes), oldest first) on an
    uplink free from `link_free_s` on (times in seconds, on one clock)."""
    free = link_free_s
    for sent_s, size in in_flight:
        free = max(free, sent_s) + size / rate_bytes_per_ms / 1000.0
    done = max(free, t_s) + frame_bytes / rate_bytes_per_ms / 1000.0
    return (done - t_s) * 1000.0 + round_trip_ms + netapp_ms


def admits(
    t_s: float,
    in_flight: Sequence[tuple[float, int]],
    frame_bytes: float,
    budget_ms: float,
    rate_bytes_per_ms: float | None,
    link_free_s: float | None,
    round_trip_ms: float,
    netapp_ms: float,
) -> bool:
    """Whether a frame of `frame_bytes` can make the budget at `t_s` behind `in_flight` (see the module); with no
    estimate yet, it goes."""
    recent = [f for f in in_flight if t_s - f[0] <= STALE_BUDGETS * budget_ms / 1000.0]
    if rate_bytes_per_ms is None or rate_bytes_per_ms <= 0 or link_free_s is None:
        return True
    args = (frame_bytes, rate_bytes_per_ms, link_free_s, round_trip_ms, netapp_ms)
    behind = predicted_latency_ms(t_s, recent, *args)
    # Only the queue ahead refuses a frame: one that would be late on an empty uplink goes (the controller answers
    # that with smaller frames, and it learns only from results).
    return behind <= budget_ms or behind <= predicted_latency_ms(t_s, (), *args)
