"""When to try a lost peer again (a camera the netapp pulls, a broker it publishes to), and what to say about it:
pure, so the threads and tasks that reconnect only sleep and log.

Exponential backoff with "equal jitter" (AWS Architecture Blog, 2015): half the step fixed, half random, so peers
lost together (a switch rebooted) are not asked again in lockstep, and no wait is ever near 0. The cap is short: an
outage is told once (`Outage`), and a peer that is back should be working again within a couple of seconds.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass

FIRST_S = 0.1
CAP_S = 1.0


def backoff_s(
    attempt: int, first_s: float = FIRST_S, cap_s: float = CAP_S, rand: Callable[[], float] = random.random
) -> float:
    """Seconds to wait before try number `attempt` (0: the first retry): min(cap, first * 2**attempt), half of it
    fixed and half scaled by `rand()` in [0, 1)."""
    step = min(cap_s, first_s * 2 ** min(max(attempt, 0), 32))
    return step / 2 + step / 2 * rand()


@dataclass
class Outage:
    """A peer's ups and downs, as a log wants them: one line when it is lost, one when it is back (with how long
    it was away), nothing per attempt in between. `now` is monotonic seconds; `kind` names what it is in those lines
    ("camera", "broker") and `cap_s` is the backoff's cap they quote."""

    name: str
    kind: str = "camera"
    cap_s: float = CAP_S
    up: bool = False
    ever: bool = False  # it was connected once
    since: float | None = None  # when the current outage began
    told: bool = False  # the current outage was logged
    attempts: int = 0  # failed tries in a row (the backoff's exponent)
    outages: int = 0  # times a working stream was lost

    def connected(self, now: float) -> str | None:
        """A connection works; the line to log (None when it was up already)."""
        if self.up:
            return None
        since, ever = self.since, self.ever
        self.up, self.ever, self.since, self.told, self.attempts = True, True, None, False, 0
        away = f" after {now - since:.1f} s" if since is not None else ""
        return f"{self.kind} {self.name}: back{away}" if ever else f"{self.kind} {self.name}: connected{away}"

    def failed(self, now: float, why: str) -> str | None:
        """A try failed, or a working stream broke; the line to log (only the first of an outage)."""
        self.attempts += 1
        if self.up:
            self.up, self.outages = False, self.outages + 1
        if self.since is None:
            self.since = now
        if self.told:
            return None
        self.told = True
        what = "lost" if self.ever else "unreachable"
        every = f"every {self.cap_s:g} s at most"
        return f"{self.kind} {self.name}: {what} ({why}); retrying quietly ({every}) till it is back"
