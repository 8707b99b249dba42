"""Between a client and its controller: each frame's bytes and the choice it was sent with, each result and miss
turned into an `Observation`, the frame rate kept, the changes and the budget share kept for the summary.

The controller is pure; this part reads the clock and is called from the robot's thread (`admit`, `sent`) and the
transports' (`result`, `missed`), so it holds a lock. A new choice goes to `apply` (the client's send settings);
`apply` runs under the lock, so two changes never cross.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from typing import Any

from netapp.accuracy import AccuracyProfile, load_profile
from netapp.client.adapt.admission import overdue
from netapp.client.adapt.controller import AdaptConfig, Choice, Controller, Observation
from netapp.client.adapt.ladder import Ladder

log = logging.getLogger(__name__)

MAX_FRAMES = 256  # frames remembered until their result (more in flight than this are not observed)
RATE_FRAMES = 16  # the robot's frame rate is measured over its last this many frames
RATE_CHANGE = 0.15  # a measured frame rate this far from the one assumed replaces it
MAX_CHANGES = 200  # changes kept for the summary (the newest; the count says how many there were)
RATE_SLACK = 0.25  # of a source frame period: a frame this early for the chosen rate still goes


def profile_named(profile: AccuracyProfile | str | None) -> AccuracyProfile | None:
    """An accuracy profile, a shipped one's name, or None (the one the netapp's processor names, once it said);
    ValueError for an unknown name."""
    if profile is None or isinstance(profile, AccuracyProfile):
        return profile
    name = profile
    loaded = load_profile(name)
    if loaded is None:
        raise ValueError(f"no accuracy profile named {name!r} (make one: python -m bench.accuracy --write)")
    return loaded


def rate_admits(now: float, due: float | None, period: float, slack: float) -> tuple[bool, float | None]:
    """Whether a frame offered at `now` goes at one frame every `period` s, and when the next one is due (`slack`: a
    frame this early still goes, a source's jitter). The due time advances by the period, not from the frame, so a
    rate between two of the source's (7.5 fps of 10) is kept on average rather than rounded down to every other
    frame; a credit of at most one period is carried (a pause does not buy a burst)."""
    if due is not None and now < due - slack:
        return False, due
    return True, max(due if due is not None else now, now - period) + period


class UplinkAdapter:
    """Feeds a `Controller` from a running client (see the module)."""

    def __init__(
        self,
        profile: AccuracyProfile | None,
        config: AdaptConfig,
        apply: Callable[[Choice], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.profile = profile  # None: the one the netapp's processor names, at `begin`
        self.off_reason: str | None = None  # why it does not adapt (no profile for the netapp's processor)
        self._begun = False
        self.config = config
        self._apply = apply
        self._clock = clock
        self._lock = threading.Lock()
        self._controller: Controller | None = None
        # timestamp -> (bytes, sent with, sent at, its predicted latency ms): in flight, until its result or miss
        self._frames: OrderedDict[int, tuple[int, Choice, float, float]] = OrderedDict()
        self._offered: deque[float] = deque(maxlen=RATE_FRAMES)  # when the robot's latest frames came
        self._changes: deque[tuple[float, Choice, dict[str, Any]]] = deque(maxlen=MAX_CHANGES)
        self._change_count = 0
        self._started_at: float | None = None
        self._due: float | None = None  # when the next frame is due at the chosen frame rate (None: any time)
        self.skipped = 0  # frames not sent to keep the chosen frame rate
        self.skipped_for_budget = 0  # frames not sent: they could not make the budget behind those in flight
        self.results = 0
        self.within_budget = 0

    def begin(
        self, source_size: tuple[int, int], input_size: tuple[int, int] | None, netapp_profile: str | None = None
    ) -> None:
        """The first frame's size (and what the netapp's processor consumes and the accuracy profile it names, if
        it said): the ladder is built and the first choice applied. Later calls do nothing."""
        with self._lock:
            if self._begun:
                return
            self._begun = True
            if self.profile is None:
                self.profile = load_profile(netapp_profile) if netapp_profile else None
                if self.profile is None:
                    # A profile says what smaller or coarser frames cost; without one, any choice could hurt the
                    # processor's results (a colour, a measurement) where it cannot be seen.
                    self.off_reason = (
                        f"the netapp's processor names no accuracy profile we have ({netapp_profile or 'none'}):"
                        " frames go as they are told (give one: accuracy_profile=...)"
                    )
                    log.info("not adapting: %s", self.off_reason)  # a choice, not a fault: the summary says it too
                    return
            cap = max(input_size) if input_size else None
            floor = self.config.accuracy_floor
            switch, jpeg = self.config.switch_codec, self.config.codec == "jpeg"
            ladder = Ladder.from_profile(
                self.profile, floor, max(source_size), max_long_side=cap, h264=switch, jpeg=jpeg
            )
            if not ladder.reaches_floor:
                log.warning(
                    "no setting of the %s profile reaches F1 %.2f: sending its best", self.profile.model, ladder.floor
                )
            self._controller = Controller(ladder, self.config)
            self._started_at = self._clock()
            self._record(self._controller.choice)

    @property
    def choice(self) -> Choice | None:
        controller = self._controller
        return controller.choice if controller is not None else None

    @property
    def ladder(self) -> Ladder | None:
        controller = self._controller
        return controller.ladder if controller is not None else None

    def admit(self) -> bool:
        """Whether the robot's next frame goes (it can make the budget behind the frames in flight, and the chosen
        frame rate has room for it); counted when it does not."""
        with self._lock:
            now = self._clock()
            self._measure_rate(now)
            # A frame that cannot make the budget behind those in flight is dropped; not while one is overdue, when
            # the newest frame waits for its result instead (`in_flight_cap`), replacing the one waiting before.
            controller = self._controller
            if controller is not None and not self._overdue(now) and not controller.admits(now, self._in_flight()):
                self.skipped_for_budget += 1
                return False
            choice = self.choice
            source_fps = self._controller.config.source_fps if self._controller else self.config.source_fps
            if choice is None or choice.fps >= source_fps:
                self._due = None
                return True
            admitted, self._due = rate_admits(now, self._due, 1.0 / choice.fps, RATE_SLACK / source_fps)
            self.skipped += not admitted
            return admitted

    def _in_flight(self) -> list[tuple[float, int]]:
        return sorted((at, size) for size, _, at, _ in self._frames.values())

    def in_flight_cap(self) -> int | None:
        """The most frames in flight now (the sender's cap): those in flight while one of them is overdue, so the next
        waits for its result (`netapp.client.adapt.admission`); None: no cap."""
        with self._lock:
            return len(self._frames) if self._overdue(self._clock()) else None

    def _overdue(self, now: float) -> bool:
        return overdue(now, [(at, ms) for _, _, at, ms in self._frames.values()], self.config.latency_budget_ms)

    def _measure_rate(self, now: float) -> None:
        self._offered.append(now)
        if self._controller is None or len(self._offered) < RATE_FRAMES:
            return
        span = self._offered[-1] - self._offered[0]
        if span <= 0:
            return
        fps = (len(self._offered) - 1) / span
        if abs(fps - self._controller.config.source_fps) > RATE_CHANGE * self._controller.config.source_fps:
            self._controller.set_source_fps(round(fps, 2))

    def sent(self, timestamp: int, bytes_sent: int) -> None:
        """A frame went on the wire with the current choice."""
        with self._lock:
            choice = self.choice
            if choice is None:
                return
            now = self._clock()
            controller = self._controller
            predicted = controller.predicted_latency_ms(now, self._in_flight(), bytes_sent) if controller else 0.0
            self._frames[timestamp] = (bytes_sent, choice, now, predicted or self.config.latency_budget_ms)
            while len(self._frames) > MAX_FRAMES:
                self._frames.popitem(last=False)

    def result(self, timestamp: int, latency_ms: float, parts: Any) -> dict[str, Any] | None:
        """A result arrived: `parts` its `LatencyBreakdown` (None: the netapp sent no stamps, nothing to learn).
        Returns what its frame was sent with (bytes and settings; None for a frame this adapter did not see)."""
        with self._lock:
            self.results += 1
            self.within_budget += latency_ms <= self.config.latency_budget_ms
            frame = self._frames.pop(timestamp, None)
            if frame is None:
                return None
            bytes_sent, choice, _, _ = frame
            if parts is not None and self._controller is not None:
                netapp_ms = parts.queue_ms + parts.inference_ms
                obs = Observation(self._clock(), choice.version, bytes_sent, latency_ms, netapp_ms)
                self._record(self._controller.observe(obs))
            return {"bytes": bytes_sent, **choice.settings()}

    def missed(self, timestamp: int) -> None:
        """A frame that will get no result in time (lost, or dropped by the netapp for its deadline)."""
        with self._lock:
            if self._frames.pop(timestamp, None) is None or self._controller is None:
                return
            self._record(self._controller.missed(self._clock()))

    def _record(self, choice: Choice | None) -> None:
        if choice is None:
            return
        self._change_count += 1
        self._changes.append((self._clock(), choice, self._estimated()))
        self._apply(choice)

    def _estimated(self) -> dict[str, Any]:
        """What the controller believed of the link (the rate, the fixed round trip, the netapp's time), rounded."""
        estimate = self._controller.estimate if self._controller is not None else None
        if estimate is None or estimate.rate_mbit is None:
            return {}
        return {
            "uplink_mbit": round(estimate.rate_mbit, 3),
            "round_trip_ms": round(estimate.round_trip_ms, 1),
            "netapp_ms": round(estimate.netapp_ms, 1),
        }

    def report(self) -> dict[str, Any]:
        """The summary's `adapt` part: the budget, the floor, the current settings, the changes over time (seconds
        since the first frame; the newest `MAX_CHANGES`), the share of results within the budget."""
        with self._lock:
            start = self._started_at or 0.0
            choice = self.choice
            estimate = self._controller.estimate if self._controller is not None else None
            return {
                "latency_budget_ms": self.config.latency_budget_ms,
                "accuracy_floor": self.config.accuracy_floor,
                "profile": self.profile.model if self.profile is not None else None,
                "off": self.off_reason,
                "settings": choice.settings() if choice else None,
                "f1": self._controller.ladder.rungs[choice.rung].f1 if choice and self._controller else None,
                "uplink_mbit": round(estimate.rate_mbit, 2) if estimate and estimate.rate_mbit else None,
                "estimate": self._estimated(),
                "changes": [
                    {"t_s": round(t - start, 2), **c.settings(), "reason": c.reason, **known}
                    for t, c, known in self._changes
                ],
                "change_count": self._change_count,
                "skipped_for_rate": self.skipped,
                "skipped_for_budget": self.skipped_for_budget,
                "within_budget": round(self.within_budget / self.results, 3) if self.results else None,
            }
