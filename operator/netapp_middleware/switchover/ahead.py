"""Deploy ahead of a moving robot (pure; no I/O, the clock passed in).

A robot may say where it is heading: a route of (pool, eta) waypoints, eta in Unix seconds. `check_route` bounds
what it may say (known pools, no time in the past or too far ahead, at most `max_waypoints`, and no flapping:
waypoints at least `min_dwell_s` apart, one pool after another). `plan_route` says, at each tick, which pools to
keep warm for it (each waypoint from `warm_lead_s` before its eta) and whether to move it now (`switch_lead_s`
before the eta, so the move is done by the time the robot gets there, never sooner than `min_dwell_s` after it
arrived where it is). `standby_needs` says which (app, placement) a warm standby must wait on: the next-best
placement of every robot of an app whose catalogue entry asks for one. `warm_plan` starts what is needed and
releases what no robot needed for `idle_grace_s`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..catalogue import STANDBY_NEXT_BEST


@dataclass(frozen=True)
class Waypoint:
    pool: str
    eta: float  # Unix seconds


@dataclass(frozen=True)
class AheadPolicy:
    max_waypoints: int = 16  # a route's length
    horizon_s: float = 3600.0  # how far ahead an eta may be
    past_tolerance_s: float = 1.0  # an eta this much in the past is still taken (clocks differ a little)
    min_dwell_s: float = 5.0  # no two moves of a robot, nor two waypoints, closer than this
    warm_lead_s: float = 60.0  # a waypoint's pool is readied this long before its eta
    switch_lead_s: float = 0.5  # the robot is moved this long before its eta
    idle_grace_s: float = 30.0  # a warm netapp no robot may need is released after this
    min_route_interval_s: float = 1.0  # a robot sends its route at most this often (else 429)

    def __post_init__(self) -> None:
        if self.max_waypoints < 1:
            raise ValueError("max_waypoints must be at least 1")
        if min(self.horizon_s, self.past_tolerance_s, self.min_dwell_s, self.warm_lead_s, self.switch_lead_s) < 0:
            raise ValueError("the route's times must not be negative")
        if min(self.idle_grace_s, self.min_route_interval_s) < 0:
            raise ValueError("idle_grace_s and min_route_interval_s must not be negative")


class RouteRefused(ValueError):
    """A route the middleware will not follow; the message says what is wrong (one line)."""


def check_route(
    waypoints: Sequence[tuple[str, float]], now: float, known: Sequence[str], policy: AheadPolicy
) -> tuple[Waypoint, ...]:
    """The route as waypoints, or RouteRefused with the first thing wrong with it (see the module)."""
    if len(waypoints) > policy.max_waypoints:
        raise RouteRefused(f"a route has at most {policy.max_waypoints} waypoints, got {len(waypoints)}")
    route: list[Waypoint] = []
    for pool, eta in waypoints:
        if pool not in known:
            raise RouteRefused(f"unknown pool {pool!r}: the middleware serves {', '.join(known)}")
        if not math.isfinite(eta) or eta < now - policy.past_tolerance_s:
            raise RouteRefused(f"the eta of {pool} is {now - eta:.1f} s in the past: give times to come (Unix s)")
        if eta > now + policy.horizon_s:
            raise RouteRefused(f"the eta of {pool} is more than {policy.horizon_s:.0f} s ahead")
        if route:
            last = route[-1]
            if eta <= last.eta:
                raise RouteRefused("the waypoints' etas must increase")
            if pool == last.pool:
                raise RouteRefused(f"{pool} follows itself: give each pool once per stay")
            if eta - last.eta < policy.min_dwell_s:
                raise RouteRefused(
                    f"flapping: {last.pool} then {pool} {eta - last.eta:.1f} s later; "
                    f"a robot stays at least {policy.min_dwell_s:.0f} s on a pool"
                )
        route.append(Waypoint(pool, float(eta)))
    return tuple(route)


def route_record(route: Sequence[Waypoint]) -> list[list[Any]]:
    """A route as the deployment's claim records it (JSON), so that a restarted middleware follows it on."""
    return [[w.pool, w.eta] for w in route]


def route_recorded(raw: Any, now: float, known: Sequence[str], policy: AheadPolicy) -> tuple[Waypoint, ...]:
    """A recorded route back (`route_record`), its waypoints still ahead only (what was passed before the restart is
    behind the robot); () for anything else than what `route_record` writes."""
    if not isinstance(raw, list) or len(raw) > policy.max_waypoints:
        return ()
    route = []
    for item in raw:
        if not (isinstance(item, list) and len(item) == 2 and item[0] in known):
            return ()
        if not isinstance(item[1], (int, float)) or not math.isfinite(item[1]):
            return ()
        if item[1] > now:
            route.append(Waypoint(str(item[0]), float(item[1])))
    return tuple(route)


@dataclass(frozen=True)
class RoutePlan:
    warm: tuple[str, ...]  # pools to keep warm for the robot now
    move_to: str | None  # move the robot there now
    route: tuple[Waypoint, ...]  # what is left of the route (waypoints passed are dropped)


def plan_route(
    route: Sequence[Waypoint], now: float, placement: str | None, arrived_at: float, policy: AheadPolicy
) -> RoutePlan:
    """What to do for a robot on `placement` (since `arrived_at`) following `route` (see the module)."""
    due = [w for w in route if w.eta - policy.switch_lead_s <= now]
    current = due[-1] if due else None  # where the robot is (about to be) now; earlier waypoints are behind it
    left = tuple(w for w in route if current is None or w.eta >= current.eta)
    warm = tuple(dict.fromkeys(w.pool for w in left if w.eta - policy.warm_lead_s <= now and w.pool != placement))
    move_to = None
    if current is not None and current.pool != placement and now - arrived_at >= policy.min_dwell_s:
        move_to = current.pool
    return RoutePlan(warm, move_to, left)


def next_best(placement: str | None, placements: Sequence[str]) -> str | None:
    """The placement a robot on `placement` would go to next: the first other one in order of preference."""
    return next((p for p in placements if p != placement), None)


def standby_needs(
    robots: Iterable[tuple[str, str | None]], standby: Mapping[str, str], placements: Sequence[str]
) -> set[tuple[str, str]]:
    """(app, placement) pairs a warm standby must wait on, for robots as (app, placement) and each app's `standby`
    (STANDBY_NEXT_BEST, or a placement)."""
    needs: set[tuple[str, str]] = set()
    for app, placement in robots:
        wanted = standby.get(app)
        target = next_best(placement, placements) if wanted == STANDBY_NEXT_BEST else wanted
        if target is not None and target != placement:
            needs.add((app, target))
    return needs


@dataclass(frozen=True)
class WarmPlan:
    start: frozenset[tuple[str, str]]  # needed and not held: hold them now
    release: frozenset[tuple[str, str]]  # held and needed by no robot for idle_grace_s
    idle_since: dict[tuple[str, str], float]  # held and not needed now: since when


def warm_plan(
    needed: set[tuple[str, str]],
    held: Iterable[tuple[str, str]],
    idle_since: Mapping[tuple[str, str], float],
    now: float,
    grace_s: float,
) -> WarmPlan:
    """Which warm netapps to start and which to release (see the module)."""
    held = set(held)
    idle = {key: idle_since.get(key, now) for key in held - needed}
    release = frozenset(key for key, since in idle.items() if now - since >= grace_s)
    return WarmPlan(frozenset(needed - held), release, {k: v for k, v in idle.items() if k not in release})
