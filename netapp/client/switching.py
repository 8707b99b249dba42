"""Policy and fallback switching: what the client does (`Mode`: the netapps frames go to, the local fallback), the
`on_switch` event when that changes, and the newest frame handed to the fallback as it takes over.

The `Policy` (`netapp.client.policy`) decides from what it learns; this part keeps it behind its own lock, so the
ledger may ask it for a route while claiming a frame, and tells the robot about each change, never raising into it.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

from netapp.client.fallback import LocalFallback
from netapp.client.ledger import Ledger
from netapp.client.policy import Mode, Policy, Route
from netapp.client.stats import ClientStats

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Switch:
    """What the client does now (`on_switch`): its state, the netapps frames go to, the local fallback, and why."""

    state: str  # connected, hedging, fallback or reconnecting
    urls: tuple[str, ...]
    local: bool
    reason: str


class Switcher:
    """The policy behind its own lock, what the client does now (`mode`), and the `Switch` events."""

    def __init__(
        self,
        policy: Policy,
        urls: Callable[[], tuple[str, ...]],
        ledger: Ledger,
        fallback: LocalFallback | None,
        deadline_ms: float | None,
        stats: ClientStats,
        on_switch: Callable[[Switch], None] | None,
    ) -> None:
        self.policy = policy
        self.on_switch = on_switch
        self._urls = urls
        self._ledger = ledger
        self._fallback = fallback
        self._deadline_ms = deadline_ms
        self._stats = stats
        self._lock = threading.Lock()  # a leaf: the ledger takes it while claiming
        self._mode = policy.mode()
        self._started = False  # switches are counted once connect() has returned
        self.on_retire: Callable[[int], None] | None = None  # a move left netapp i behind: the client closes it

    @property
    def mode(self) -> Mode:
        return self._mode

    def route(self, now_ns: int) -> Route:
        with self._lock:
            return self.policy.route(now_ns)

    def up(self, i: int) -> None:
        with self._lock:
            self.policy.up(i)

    def down(self, i: int) -> None:
        with self._lock:
            self.policy.down(i)

    def add(self) -> int:
        with self._lock:
            return self.policy.add()

    def begin_move(self, old: int, new: int, now_ns: int) -> None:
        with self._lock:
            self.policy.begin_move(old, new, now_ns)

    def finish_move(self, reason: str) -> None:
        with self._lock:
            self.policy.finish_move()
        self.update(reason)

    def learn(self, i: int, on_time: bool) -> None:
        """A frame sent to netapp `i` ended within its deadline or not (call `update` once after several)."""
        with self._lock:
            self.policy.outcome(i, on_time)

    def outcome(self, i: int, on_time: bool, reason: str) -> None:
        self.learn(i, on_time)
        self.update(reason)

    def start(self, reason: str) -> None:
        """connect() has returned: from now on each switch is counted."""
        self.update(reason)
        self._started = True

    def update(self, reason: str) -> Mode:
        """After the policy learned something: when what the client does changed, count it and tell the robot."""
        with self._lock:
            mode = self.policy.mode()
            changed, self._mode = mode != self._mode, mode
            retired = self.policy.retired()
        for i in retired:
            if self.on_retire is not None:
                self.on_retire(i)
        if not changed:
            return mode
        if mode.local and self._fallback is not None and self._deadline_ms is not None:
            takeover = self._ledger.take_over_newest(self._deadline_ms * 1e6)
            if takeover is not None:
                self._fallback.submit(*takeover)
        urls = self._urls()
        switch = Switch(mode.state, tuple(urls[i] for i in mode.netapps), mode.local, reason)
        if self._started:
            self._stats.add(switches=1)
        log.info("%s: now %s", reason, doing(mode, urls))
        if self.on_switch is not None:
            try:
                self.on_switch(switch)
            except Exception:
                log.exception("on_switch callback failed")
        return mode


def doing(mode: Mode, urls: tuple[str, ...]) -> str:
    """What the client does, in words, for on_error and the log."""
    names = ", ".join(urls[i] for i in mode.netapps)
    if mode.local:
        return f"processing frames locally ({mode.state})" + (f" while trying {names}" if names else "")
    if not mode.netapps:
        return "no netapp is connected (reconnecting)"
    return f"frames go to {names} ({mode.state})"
