"""What a link does over time: outages that come and go, and delay, loss or rates that change mid-run. Pure
functions.

Times are seconds since the emulator started. A schedule is given with the profile to ``LinkEmulator``:

    LinkSchedule(outages=Outages(down_s=3, every_s=20))                 # 3 s down every 20 s, first at t=20
    LinkSchedule(changes=(Change(30, delay_ms=150),))                  # delay 10 -> 150 ms at t=30
    LinkSchedule(changes=(Change(20, up_mbit=1.5),))                   # the uplink capped at 1.5 Mbit/s at t=20
    parse_outages("3/20"), parse_change("30:delay=150,loss=1,up=2")    # the same from the command line
    parse_trace(text)                                                  # a rate trace: lines of "TIME UP DOWN"
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass

from .profiles import LinkProfile


@dataclass(frozen=True)
class Outages:
    """The link is down for ``down_s`` at ``first_s``, ``first_s + every_s``, ... (default ``first_s = every_s``,
    so a run starts on a working link). Down means every packet is lost, both ways, until it is up again."""

    down_s: float
    every_s: float
    first_s: float | None = None

    def __post_init__(self) -> None:
        if not 0 < self.down_s < self.every_s:
            raise ValueError(f"an outage lasts over 0 s and less than its period, got {self.down_s}/{self.every_s}")
        if self.first_s is not None and self.first_s < 0:
            raise ValueError("the first outage cannot start before the link does")

    @property
    def start_s(self) -> float:
        return self.every_s if self.first_s is None else self.first_s

    def window(self, t: float) -> tuple[float, float] | None:
        """The outage ``(start, end)`` that covers ``t``, or None while the link is up."""
        if t < self.start_s:
            return None
        k = math.floor((t - self.start_s) / self.every_s)
        start = self.start_s + k * self.every_s
        return (start, start + self.down_s) if t < start + self.down_s else None

    def windows(self, until: float) -> list[tuple[float, float]]:
        """Every outage that starts before ``until`` (for plots: the shaded spans)."""
        out, start = [], self.start_s
        while start < until:
            out.append((start, start + self.down_s))
            start += self.every_s
        return out

    def edges(self) -> Iterator[float]:
        """Times the link goes down or comes back, in order, without end."""
        start = self.start_s
        while True:
            yield start
            yield start + self.down_s
            start += self.every_s


@dataclass(frozen=True)
class Change:
    """From ``at_s`` on, the link has these figures (None: unchanged)."""

    at_s: float
    delay_ms: float | None = None
    jitter_ms: float | None = None
    loss_pct: float | None = None
    up_mbit: float | None = None  # the uplink's rate (robot -> netapp), Mbit/s
    down_mbit: float | None = None

    def __post_init__(self) -> None:
        if self.at_s < 0:
            raise ValueError("a change cannot happen before the link starts")

    def apply(self, profile: LinkProfile) -> LinkProfile:
        fields = {
            "delay_ms": self.delay_ms,
            "jitter_ms": self.jitter_ms,
            "loss_pct": self.loss_pct,
            "rate_mbit_up": self.up_mbit,
            "rate_mbit_down": self.down_mbit,
        }
        return dataclasses.replace(profile, **{k: v for k, v in fields.items() if v is not None})


@dataclass(frozen=True)
class LinkState:
    """The link at one moment: its figures, and whether it is down (and until when)."""

    profile: LinkProfile
    down_until: float | None = None

    @property
    def down(self) -> bool:
        return self.down_until is not None


@dataclass(frozen=True)
class LinkSchedule:
    """Changes of figures (steps, in time order) and periodic outages; empty: the profile all along."""

    changes: tuple[Change, ...] = ()
    outages: Outages | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "changes", tuple(sorted(self.changes, key=lambda c: c.at_s)))

    @property
    def is_static(self) -> bool:
        return not self.changes and self.outages is None

    def profile_at(self, base: LinkProfile, t: float) -> LinkProfile:
        """``base`` with every change due by ``t`` applied (checked like any profile)."""
        profile = base
        for change in self.changes:
            if change.at_s > t:
                break
            profile = change.apply(profile)
        return profile

    def state_at(self, base: LinkProfile, t: float) -> LinkState:
        window = self.outages.window(t) if self.outages is not None else None
        return LinkState(self.profile_at(base, t), None if window is None else window[1])

    def edges(self) -> Iterator[float]:
        """Times at which :meth:`state_at` may change, in order (without end when there are outages)."""
        changes = iter(c.at_s for c in self.changes)
        outages = self.outages.edges() if self.outages is not None else iter(())
        nxt_change, nxt_outage = next(changes, None), next(outages, None)
        while nxt_change is not None or nxt_outage is not None:
            if nxt_outage is None or (nxt_change is not None and nxt_change <= nxt_outage):
                yield nxt_change  # type: ignore[misc]
                nxt_change = next(changes, None)
            else:
                yield nxt_outage
                nxt_outage = next(outages, None)

    def outage_windows(self, until: float) -> list[tuple[float, float]]:
        return self.outages.windows(until) if self.outages is not None else []


def parse_outages(text: str) -> Outages:
    """``DOWN/EVERY[+FIRST]`` in seconds: ``3/20`` is 3 s down every 20 s from t=20; ``3/20+5`` from t=5."""
    try:
        down, _, rest = text.partition("/")
        every, _, first = rest.partition("+")
        return Outages(float(down), float(every), float(first) if first else None)
    except ValueError as exc:
        raise ValueError(f"expected DOWN/EVERY[+FIRST] in seconds (like 3/20), got {text!r}: {exc}") from None


_CHANGE_KEYS = {"delay": "delay_ms", "jitter": "jitter_ms", "loss": "loss_pct", "up": "up_mbit", "down": "down_mbit"}
CHANGE_FORMAT = "T:delay=MS,jitter=MS,loss=PCT,up=MBIT,down=MBIT"
MAX_TRACE_ROWS = 100_000  # a trace of 10 rows a second for almost 3 hours; a bigger file is refused unread


def parse_change(text: str) -> Change:
    """``T:KEY=VALUE,...`` with any of delay (ms), jitter (ms), loss (%), up and down (Mbit/s): ``30:delay=150``
    sets the delay to 150 ms at t=30 s, ``20:up=1.5`` caps the uplink at 1.5 Mbit/s from t=20 s."""
    at, _, assignments = text.partition(":")
    fields: dict[str, float] = {}
    try:
        for item in filter(None, assignments.split(",")):
            key, _, value = item.partition("=")
            if key not in _CHANGE_KEYS:
                raise ValueError(f"unknown figure {key!r}; known: {', '.join(_CHANGE_KEYS)}")
            fields[_CHANGE_KEYS[key]] = float(value)
        if not fields:
            raise ValueError("nothing to change")
        return Change(float(at), **fields)
    except ValueError as exc:
        raise ValueError(f"expected {CHANGE_FORMAT} (like 30:delay=150 or 20:up=1.5), got {text!r}: {exc}") from None


def parse_trace(text: str) -> tuple[Change, ...]:
    """A rate trace: one ``TIME UP DOWN`` row a line (seconds, Mbit/s, Mbit/s; spaces, tabs or commas between;
    ``#`` starts a comment; ``-`` leaves that direction as it is), times increasing. Each row is a change of the
    link's rates at that time; with a profile's delay and loss they make a swinging link."""
    changes: list[Change] = []
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split("#", 1)[0].replace(",", " ").split()
        if not fields:
            continue
        if len(changes) >= MAX_TRACE_ROWS:
            raise ValueError(f"a trace has at most {MAX_TRACE_ROWS} rows")
        try:
            if len(fields) != 3:
                raise ValueError(f"{len(fields)} fields")
            at, up, down = (None if f == "-" else float(f) for f in fields)
            if at is None:
                raise ValueError("the time cannot be -")
            if changes and at <= changes[-1].at_s:
                raise ValueError(f"time {at:g} s does not follow {changes[-1].at_s:g} s")
            change = Change(at, up_mbit=up, down_mbit=down)
            for rate in (up, down):
                if rate is not None and not 0 < rate < math.inf:
                    raise ValueError(f"a rate must be over 0 Mbit/s, got {rate:g}")
        except ValueError as exc:
            raise ValueError(f"trace line {number}: expected TIME UP DOWN (seconds, Mbit/s, Mbit/s): {exc}") from None
        changes.append(change)
    if not changes:
        raise ValueError("the trace has no rows (expected lines of TIME UP DOWN)")
    return tuple(changes)


MAX_TRACE_BYTES = 4 << 20


def read_trace(path: str) -> tuple[Change, ...]:
    """:func:`parse_trace` of a file (at most 4 MiB), with the file's name in any error."""
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_TRACE_BYTES + 1)
    except OSError as exc:
        raise ValueError(f"cannot read the trace {path}: {exc.strerror}") from None
    if len(data) > MAX_TRACE_BYTES:
        raise ValueError(f"the trace {path} is over {MAX_TRACE_BYTES >> 20} MiB")
    try:
        return parse_trace(data.decode("utf-8", errors="replace"))
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
