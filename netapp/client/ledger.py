"""The ledger of frames the client has taken from the robot: the newest one waiting for a slot, and those in flight
at netapps (and the fallback) until each target has answered, dropped or lost them.

A frame is *claimed* when the route gives it targets (netapp indexes, `FALLBACK_TARGET`), *settled* at a target that is
done with it, *lost* at a target that will not answer (counted lost once nobody answered it and nobody still holds
it), and *expired* by age: past its deadline it is a miss where it still waits, past the result timeout it is lost
everywhere. One condition variable guards it all and wakes whoever waits for a slot; no I/O happens under it.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field

from netapp.client.encoders import Frame
from netapp.client.errors import NetAppError
from netapp.client.stats import ClientStats

FALLBACK_TARGET = -1  # the target index of the robot's own fallback processor

# Where a frame may go now: (now in monotonic ns, frames in flight at netapp i) -> target indexes ([]: it waits).
# Called with the ledger's lock held: it may take only leaf locks (the policy's, a link's, the wire's tickets).
Router = Callable[[int, Callable[[int], int]], list[int]]


@dataclass
class InFlight:
    """A frame handed to netapps (or the fallback) and not settled everywhere yet."""

    sent_ns: int
    waiting: set[int]  # targets that may still answer
    answered: bool = False
    missed: dict[int, int] = field(default_factory=dict)  # netapp -> the misses counted there for this frame


@dataclass(frozen=True)
class Claim:
    """A frame that got its slots: where it goes, and its turn on the wire."""

    timestamp: int
    frame: Frame
    targets: tuple[int, ...]
    ticket: int
    sent_ns: int = 0  # when it was claimed (monotonic): its result's latency counts from here


class Ledger:
    """The frames between `send()` and their answers, under one condition variable (see the module)."""

    def __init__(self, stats: ClientStats, next_ticket: Callable[[], int], closed: threading.Event) -> None:
        self._stats = stats
        self._next_ticket = next_ticket
        self._closed = closed
        self._cond = threading.Condition()
        self._frames: dict[int, InFlight] = {}  # by timestamp
        self._at: defaultdict[int, set[int]] = defaultdict(set)  # netapp index -> timestamps in flight there
        self._waiting: tuple[int, Frame] | None = None  # the newest frame without a slot yet (newest wins)
        self._newest: tuple[int, Frame] | None = None  # the newest frame claimed: the fallback may take it over
        self._last_timestamp = 0

    # -- taking frames ---------------------------------------------------------------------------------------------

    def offer(self, frame: Frame, timestamp: int | None, route: Router) -> tuple[int, Claim | None]:
        """A frame from the robot: its timestamp, and its claim when a slot is free now (else it waits, replacing
        an older waiting frame, which is counted dropped)."""
        with self._cond:
            if self._closed.is_set():
                raise NetAppError("the client is closed")
            if timestamp is None:
                timestamp = max(time.time_ns(), self._last_timestamp + 1)
            self._last_timestamp = max(self._last_timestamp, timestamp)
            claim = self._claim(timestamp, frame, route) if self._waiting is None else None
            if claim is None:
                if self._waiting is not None:
                    self._stats.add(dropped_client=1)
                self._waiting = (timestamp, frame)
                self._cond.notify_all()
        return timestamp, claim

    def claim_waiting(self, route: Router, sleep_s: Callable[[bool], float]) -> Claim | None:
        """For the sender thread: the waiting frame's claim when it may go now; else None after waiting up to
        `sleep_s(a frame waits)` seconds for a change."""
        with self._cond:
            if self._closed.is_set():
                return None
            if self._waiting is not None and (claim := self._claim(*self._waiting, route)) is not None:
                self._waiting = None
                return claim
            self._cond.wait(timeout=sleep_s(self._waiting is not None))
            return None

    def _claim(self, timestamp: int, frame: Frame, route: Router) -> Claim | None:
        now = time.monotonic_ns()
        targets = route(now, lambda i: len(self._at[i]))
        if not targets:
            return None
        self._frames[timestamp] = InFlight(now, set(targets))
        self._newest = (timestamp, frame)
        for i in targets:
            if i != FALLBACK_TARGET:
                self._at[i].add(timestamp)
        return Claim(timestamp, frame, tuple(targets), self._next_ticket(), now)

    def take_over_newest(self, deadline_ns: float) -> tuple[int, Frame] | None:
        """As the fallback starts: the newest frame claimed, if no one answered it yet and it is younger than
        `deadline_ns`, goes to the fallback too (it would otherwise wait for the next frame)."""
        with self._cond:
            if self._newest is None:
                return None
            timestamp, frame = self._newest
            sent = self._frames.get(timestamp)
            if sent is None or sent.answered or FALLBACK_TARGET in sent.waiting:
                return None
            if time.monotonic_ns() - sent.sent_ns > deadline_ns:
                return None
            sent.waiting.add(FALLBACK_TARGET)
            return timestamp, frame

    # -- settling them ---------------------------------------------------------------------------------------------

    def settle(self, target: int, timestamp: int | None) -> InFlight | None:
        """`target` is done with a frame; returns the frame's record, None if it was not waiting there."""
        with self._cond:
            return self._settle(target, timestamp)

    def _settle(self, target: int, timestamp: int | None) -> InFlight | None:
        self._at[target].discard(timestamp)  # type: ignore[arg-type]
        sent = self._frames.get(timestamp)  # type: ignore[arg-type]
        if sent is None or target not in sent.waiting:
            return None
        sent.waiting.discard(target)
        if not sent.waiting:
            del self._frames[timestamp]  # type: ignore[arg-type]
        self._cond.notify_all()
        return sent

    def lose(self, target: int, timestamp: int | None) -> InFlight | None:
        """`target` will not answer a frame: settled there, and counted lost when nobody answered it and nobody else
        still holds it. Returns the frame's record (None if it was not waiting there)."""
        with self._cond:
            sent = self._settle(target, timestamp)
            if sent is not None and not sent.waiting and not sent.answered:
                self._stats.add(lost=1)
            return sent

    def lose_all_at(self, target: int) -> None:
        """The connection to netapp `target` dropped or was closed: its frames in flight will get no result."""
        with self._cond:
            for timestamp in list(self._at[target]):
                sent = self._settle(target, timestamp)
                if sent is not None and not sent.waiting and not sent.answered:
                    self._stats.add(lost=1)

    def answer(self, sent: InFlight) -> bool:
        """A result for this frame arrived: True for the first one (it wins), False for any later one."""
        with self._cond:
            first, sent.answered = not sent.answered, True
            return first

    def expire(self, miss_after_ns: float | None, timeout_ns: int, again_ns: float | None = None) -> list[int]:
        """A frame older than `miss_after_ns` (None: no deadline) is a miss where it waits (its result may still
        come, late), and one more for each further `again_ns` it goes unanswered there (None: once); one older than
        `timeout_ns` is lost there, freeing its slots. Returns the netapps that just missed a deadline, one entry
        per miss.

        Counting again matters when a netapp holds the client's only slot (the pacer's window of one frame) and
        goes silent: the frames held back behind that one miss their deadlines too, and a link that is down for
        seconds must not count as one miss, or the policy never gives up on it (nor starts the fallback)."""
        now = time.monotonic_ns()
        missed: list[int] = []
        with self._cond:
            for timestamp, sent in list(self._frames.items()):
                age = now - sent.sent_ns
                if miss_after_ns is not None and age > miss_after_ns:
                    due = 1 if not again_ns else 1 + int((age - miss_after_ns) // again_ns)
                    for i in sent.waiting - {FALLBACK_TARGET}:
                        new = due - sent.missed.get(i, 0)
                        if new > 0:
                            sent.missed[i] = due
                            missed.extend([i] * new)
                if age > timeout_ns:
                    for i in sent.waiting - {FALLBACK_TARGET}:
                        self._at[i].discard(timestamp)
                    sent.waiting.clear()
                    if not sent.answered:
                        self._stats.add(lost=1)
                    del self._frames[timestamp]
                    self._cond.notify_all()
        return missed

    # -- reading it ------------------------------------------------------------------------------------------------

    def holds(self, target: int, timestamp: object) -> bool:
        """Whether the frame is still in flight at `target` (not a stale answer from before a reconnect)."""
        with self._cond:
            return timestamp in self._at[target]

    def sent_ns(self, timestamp: object) -> int | None:
        with self._cond:
            sent = self._frames.get(timestamp)  # type: ignore[arg-type]
            return sent.sent_ns if sent is not None else None

    def wait_clear(self, target: int, timeout_s: float) -> bool:
        """Wait up to `timeout_s` until no frame is in flight at `target`; whether that is so."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._at[target], timeout=timeout_s)

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait up to `timeout_s` until no frame waits for a slot and none is in flight; whether that is so."""
        with self._cond:
            return self._cond.wait_for(lambda: self._waiting is None and not self._frames, timeout=timeout_s)

    def close(self) -> bool:
        """Take no more frames and wake the sender; False when it was closed already."""
        with self._cond:
            if self._closed.is_set():
                return False
            self._closed.set()
            self._cond.notify_all()
            return True

    def poke(self) -> None:
        """Something a route depends on changed (a netapp came up, the client closes): the sender looks again."""
        with self._cond:
            self._cond.notify_all()
