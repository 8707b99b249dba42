"""Which netapps a frame goes to, and when the robot's own processor takes over: pure, the clock passed in.

A robot may know several netapps (say the edge and the cloud deployment of one app), in order of preference. What
the client learns about each one arrives here: it is up or down (the transport's connection), and each frame sent
to it ended on time or not (a result within the deadline; or a late result, a `deadline` drop, an error, or no
result by the deadline). A netapp that missed `miss_limit` deadlines in a row is *failing* until it is on time again.

* `primary`: every frame to the first netapp that is not failing; a failing netapp earlier in the list gets a probe
  frame every `probe_interval_s` (also a frame), so the client goes back as soon as it is on time again.
* `hedge`: every frame to every netapp that is up; the client keeps the first result.
* `adaptive`: like `primary` on the first netapp while it meets its deadlines; from its first miss, every frame to
  every netapp that is up, until the first netapp has been on time `recover_after` times in a row.

When no netapp is up and on time, frames go to every netapp that is up (so a recovery is seen at once) and, with a
local fallback, to the robot's own processor too.

A move (`begin_move(old, new)`, a switchover the middleware asked for) hedges every frame across both until the new
netapp has answered on time `recover_after` times in a row; then the old one is *retired*: it gets no frame again
(`retired()` says which, once, so the client closes it). A move that has not got there in `move_timeout_s` ends:
the old one is retired if the new one is up, else the move is given up.
"""

from __future__ import annotations

from dataclasses import dataclass

POLICIES = ("primary", "hedge", "adaptive")
# What the client is doing, `NetAppClient.state`.
CONNECTED, HEDGING, FALLBACK, RECONNECTING = "connected", "hedging", "fallback", "reconnecting"


@dataclass(frozen=True)
class Route:
    """Where one frame goes: netapps by index (first the ones the mode uses, then probes), and the local fallback."""

    netapps: tuple[int, ...]
    local: bool = False
    probes: tuple[int, ...] = ()


@dataclass(frozen=True)
class Mode:
    """What the client is doing, without probes: an event when it changes."""

    state: str
    netapps: tuple[int, ...]
    local: bool


@dataclass
class NetAppHealth:
    up: bool = False
    misses: int = 0  # deadlines missed in a row
    on_time: int = 0  # deadlines met in a row
    last_probe_ns: int = -(1 << 62)
    retired: bool = False  # left behind by a move: never routed to again


@dataclass(frozen=True)
class Move:
    old: int
    new: int
    deadline_ns: int


class Policy:
    """Routing of frames over netapps `0 .. count-1` (in order of preference) and an optional local fallback."""

    def __init__(
        self,
        kind: str = "primary",
        count: int = 1,
        *,
        fallback: bool = False,
        miss_limit: int = 2,
        recover_after: int = 3,
        probe_interval_s: float = 1.0,
        move_timeout_s: float = 10.0,
    ) -> None:
        if kind not in POLICIES:
            raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {kind!r}")
        if count < 1:
            raise ValueError("give at least one netapp")
        if miss_limit < 1 or recover_after < 1:
            raise ValueError("miss_limit and recover_after must be at least 1")
        self.kind = kind
        self.fallback = fallback
        self.miss_limit = miss_limit
        self.recover_after = recover_after
        self.probe_interval_ns = int(probe_interval_s * 1e9)
        self.health = [NetAppHealth() for _ in range(count)]
        self._hedging = False  # adaptive: the first netapp missed a deadline and has not recovered yet
        self.move_timeout_ns = int(move_timeout_s * 1e9)
        self._move: Move | None = None
        self._retired: list[int] = []  # retired and not yet told (`retired`)

    # -- what the client learns ------------------------------------------------------------------------------------

    def up(self, i: int) -> None:
        """Netapp `i` is connected (again): it gets frames at once, and is failing only after new misses."""
        self.health[i] = NetAppHealth(up=True, retired=self.health[i].retired)

    def down(self, i: int) -> None:
        self.health[i].up = False
        if i == self.first:
            self._hedging = True

    # -- moves -----------------------------------------------------------------------------------------------------

    def add(self) -> int:
        """One more netapp (down until `up`): its index."""
        self.health.append(NetAppHealth())
        return len(self.health) - 1

    def begin_move(self, old: int, new: int, now_ns: int) -> None:
        """Move from netapp `old` to `new` (a retired one is taken back into service): hedge until `new` is on time."""
        self.health[new] = NetAppHealth(up=self.health[new].up)
        self._move = Move(old, new, now_ns + self.move_timeout_ns)

    def retired(self) -> list[int]:
        """Netapps retired since the last call (the client closes them)."""
        told, self._retired = self._retired, []
        return told

    def finish_move(self) -> None:
        """Retire the old netapp now if the new one is up (nothing to hedge: no frame is on its way)."""
        if self._move is not None and self.health[self._move.new].up:
            self._end_move(retire=True)

    def _end_move(self, retire: bool) -> None:
        move, self._move = self._move, None
        if move is not None and retire:
            self.health[move.old].retired = True
            self._retired.append(move.old)
            if move.old == 0:
                self._hedging = False

    @property
    def moving(self) -> bool:
        return self._move is not None

    @property
    def first(self) -> int:
        """The most preferred netapp still in service."""
        return next((i for i, h in enumerate(self.health) if not h.retired), 0)

    def outcome(self, i: int, on_time: bool) -> None:
        """A frame sent to netapp `i` ended within its deadline, or not."""
        h = self.health[i]
        if on_time:
            h.misses, h.on_time = 0, h.on_time + 1
        else:
            h.misses, h.on_time = h.misses + 1, 0
        if i == self.first:
            if not on_time:
                self._hedging = True
            elif h.on_time >= self.recover_after:
                self._hedging = False
        if self._move is not None and i == self._move.new and h.on_time >= self.recover_after:
            self._end_move(retire=True)

    # -- what the client does --------------------------------------------------------------------------------------

    def good(self, i: int) -> bool:
        """Up and not failing."""
        h = self.health[i]
        return h.up and h.misses < self.miss_limit

    def mode(self) -> Mode:
        up = tuple(i for i, h in enumerate(self.health) if h.up and not h.retired)
        good = [i for i in up if self.good(i)]
        if not good:
            if self.fallback:
                return Mode(FALLBACK, up, True)
            return Mode(RECONNECTING if not up else (HEDGING if len(up) > 1 else CONNECTED), up, False)
        hedge = self.kind == "hedge" or self._move is not None
        if hedge or (self.kind == "adaptive" and (self._hedging or not self.good(self.first))):
            return Mode(HEDGING if len(up) > 1 else CONNECTED, up, False)
        return Mode(CONNECTED, (good[0],), False)

    def route(self, now_ns: int) -> Route:
        """Where the next frame goes (a probe sent now is remembered, so the next one waits its interval)."""
        if self._move is not None and now_ns > self._move.deadline_ns:
            self._end_move(retire=self.health[self._move.new].up)
        mode = self.mode()
        probes: tuple[int, ...] = ()
        if mode.state == CONNECTED and len(mode.netapps) == 1 and self.kind != "hedge":
            active = mode.netapps[0]
            due = [
                i
                for i in range(active)
                if self.health[i].up
                and not self.health[i].retired
                and now_ns - self.health[i].last_probe_ns >= self.probe_interval_ns
            ]
            for i in due:
                self.health[i].last_probe_ns = now_ns
            probes = tuple(due)
        return Route(mode.netapps, mode.local, probes)
