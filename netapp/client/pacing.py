"""When the next frame may go to a netapp: a window of frames in flight and a send delay, learnt from the queue
wait that each result reports (pure; times in ns).

A netapp serves its robots in turn. When it is the bottleneck, a robot that sends at its camera's rate only fills
the netapp's one-frame queue with frames that a newer one supersedes: uplink spent for nothing (on 5G, the scarce
direction), and CPU the netapp needs for inference spent receiving and refusing them. A robot that instead waits
for each result (one frame in flight) spends nothing in vain, but its frame then queues behind every other robot's
and is old when its turn comes.

The pacer does what TCP's congestion control does with a round trip, with the netapp's own measure of its queue:
each result says how long its frame waited (`timestamp_before_process - recv_timestamp`) and how long the batch
took (`timestamp_after_process - timestamp_before_process`). While frames wait longer than `target_batches` (2)
batches, the netapp is congested: one frame in flight, and the next one is held back after each result by `gain`
(a half) of that result's excess wait, so the frame reaches the netapp nearer its turn, picked later (so fresher).
When frames wait less there is no hold; once a frame's turn came at once (it waited less than a batch: no other
robot was ahead), the window opens one frame per result back to `max_in_flight`, which hides the link's round trip
when the netapp has time to spare. A frame superseded at the netapp closes the window at once, for `CALM_RESULTS`
results at least.

A netapp that says when it will take the robot's next frame (the next-turn hint of each result,
`docs/client.md#the-next-turn-hint`) is believed instead: the next frame is held back until it would arrive
`hint_lead_batches` (one) batch before that turn, the link's round trip counted, so it waits about a batch rather
than several.
"""

from __future__ import annotations

from dataclasses import dataclass

MAX_DELAY_NS = 1_000_000_000  # never hold a frame back longer than this, whatever a netapp reports
# After a frame was superseded, this many results pass before the window may open again: a netapp with two lanes
# often serves a frame at once, and the window would otherwise open and close again every few results.
CALM_RESULTS = 16


@dataclass
class Pacer:
    max_in_flight: int
    gain: float = 0.5  # of the excess wait; 1 would overshoot: a hold shortens the next wait by as much
    # A frame may wait this many batches: the netapp always has a frame ready, even when a robot's frame comes a
    # little late (measured in docs/benchmarks.md#pacing: 1 batch left the netapp idle at times).
    target_batches: float = 2.0
    window: int = 0  # frames allowed in flight now (0: start at max_in_flight)
    delay_ns: int = 0  # how long after a result the next frame is held back
    not_before_ns: int = 0  # the next frame goes no earlier than this (monotonic ns)
    calm: int = 0  # results to pass before the window may open again (after a superseded frame)
    # With the netapp's next-turn hint: a frame is meant to arrive this many batches before its turn, room for the
    # hint's error and the link's jitter (a frame that comes after its turn waits a whole round)
    hint_lead_batches: float = 1.0

    def __post_init__(self) -> None:
        if self.window <= 0:
            self.window = self.max_in_flight

    def allows(self, in_flight: int, now_ns: int) -> bool:
        """Whether one more frame may go now, with `in_flight` frames awaiting their results."""
        return in_flight < self.window and now_ns >= self.not_before_ns

    def wait_ns(self, now_ns: int) -> int:
        """How long until the delay allows a frame (0: now)."""
        return max(0, self.not_before_ns - now_ns)

    def on_result(
        self, now_ns: int, queued_ns: int, batch_ns: int, next_turn_ns: float | None = None, link_ns: float = 0.0
    ) -> None:
        """A result arrived: its frame waited `queued_ns` at the netapp, whose batch took `batch_ns`; the netapp
        takes our next frame `next_turn_ns` after it sent this result (its hint; None: it gave none), and the link
        takes `link_ns` both ways (the result's way here and the frame's way there)."""
        excess = queued_ns - self.target_batches * batch_ns
        if next_turn_ns is not None:
            hold = next_turn_ns - link_ns - self.hint_lead_batches * batch_ns
        else:
            # From this result alone, no state carried over: robots that share a netapp see the same waits and so
            # settle on the same hold. (An integral controller, which adds to the last hold, let each robot's hold
            # drift apart and cost the fair share: 0.77 to 0.81 against 0.97 to 0.99 at 8 robots on two lanes.)
            hold = self.gain * excess
        self.delay_ns = int(min(MAX_DELAY_NS, max(0.0, hold)))
        if excess > 0:
            self.window = 1
        elif self.calm > 0:
            self.calm -= 1
        elif self.delay_ns == 0 and queued_ns < batch_ns:  # its turn came at once: the netapp has time to spare
            self.window = min(self.max_in_flight, self.window + 1)
        self.not_before_ns = now_ns + self.delay_ns

    def on_superseded(self) -> None:
        """The netapp dropped a frame of ours for a newer one: it has no room for two."""
        self.window, self.calm = 1, CALM_RESULTS

    def reset(self) -> None:
        """A new session (a reconnect, a move, another URL): nothing learnt applies."""
        self.window, self.delay_ns, self.not_before_ns, self.calm = self.max_in_flight, 0, 0, 0
