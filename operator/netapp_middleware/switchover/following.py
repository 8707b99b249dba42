"""Following robots ahead of their moves: their routes (the pools they head for, readied before they arrive, the
robot moved there on time) and the warm standbys of catalogue apps that ask for one. The decisions are pure
(`ahead.py`); this keeps the routes and the warm holds, ticks on the event loop, and tells why (Events, the log).

A warm netapp is an ordinary shared instance of (app, placement) held by a warm claim (`Registry.hold`), so a robot
deploying or moving there takes it as it is, Ready, and robots of the app share it. The registry records the hold
with the NetApp, so a restarted middleware takes it back (`_take_back`) rather than warming another.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

from ..backends.base import FAILED
from ..catalogue import Catalogue, render_spec
from ..deployments import Deployment, QuotaExceeded, Registry, Unrunnable
from ..instances import Instance, robot_claims, warm_claim
from .ahead import (
    AheadPolicy,
    RouteRefused,
    Waypoint,
    check_route,
    plan_route,
    route_record,
    route_recorded,
    standby_needs,
    warm_plan,
)

log = logging.getLogger(__name__)

WARMING, RELEASED = "StandbyWarming", "StandbyReleased"  # Kubernetes Event reasons
CATALOGUE_EVERY_S = 1.0  # how often the tick reads the catalogue (a source may read a file)
ROUTE_META = "route"  # where a deployment's claim records its route (`ahead.route_record`)

Key = tuple[str, str]  # (app, placement)
Mover = Callable[[Deployment, str, str], bool]  # (deployment, placement, why) -> a move started


class TooSoon(Exception):
    """A robot sent its route again sooner than `AheadPolicy.min_route_interval_s` after the last one."""


class Following:
    """Routes and warm standbys; `tick` once in a while (`run`)."""

    def __init__(
        self,
        registry: Registry,
        catalogue: Callable[[], Catalogue],
        placements: Sequence[str],
        policy: AheadPolicy,
        move: Mover,
        *,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.registry = registry
        self.catalogue = catalogue
        self.placements = list(placements)
        self.policy = policy
        self.move = move
        self.clock = clock
        self.routes: dict[str, tuple[Waypoint, ...]] = {}
        self.held: dict[Key, Instance] = {}
        self.idle_since: dict[Key, float] = {}
        self._route_at: dict[str, float] = {}  # deployment -> when its route last came
        self._apps: tuple[float, Catalogue] | None = None
        self.refused = 0  # routes refused (bad, or too frequent)
        self._untold: dict[Key, str] = {}  # warm-ups not announced yet: the backend has not reported them
        self._taken_back = False  # what a previous middleware recorded (`_take_back`, the first tick)

    # -- robots' routes ----------------------------------------------------------------------------------------------

    def check(self, waypoints: Sequence[tuple[str, float]]) -> tuple[Waypoint, ...]:
        """The route as the middleware would follow it; raises RouteRefused (counted, one log line)."""
        try:
            return check_route(waypoints, self.clock(), self.placements, self.policy)
        except RouteRefused as exc:
            self.refused += 1
            log.info("route refused: %s", exc)
            raise

    def set_route(self, deployment: Deployment, waypoints: Sequence[tuple[str, float]]) -> tuple[Waypoint, ...]:
        """Take a robot's route (replacing the last one; empty: none). Raises RouteRefused, TooSoon."""
        now = self.clock()
        if now - self._route_at.get(deployment.id, float("-inf")) < self.policy.min_route_interval_s:
            self.refused += 1
            raise TooSoon(f"at most one route per {self.policy.min_route_interval_s:g} s")
        route = self.check(waypoints)
        self._route_at[deployment.id] = now
        if route:
            self.routes[deployment.id] = route
            deployment.meta[ROUTE_META] = route_record(route)
            log.info("deployment %s heads for %s", deployment.id, ", ".join(f"{w.pool}@{w.eta:.1f}" for w in route))
        else:
            self.routes.pop(deployment.id, None)
            deployment.meta.pop(ROUTE_META, None)
        self.registry.record(deployment)  # with its claims: a restarted middleware follows it on
        return route

    def route_of(self, deployment_id: str) -> list[dict[str, Any]]:
        return [{"pool": w.pool, "eta": w.eta} for w in self.routes.get(deployment_id, ())]

    # -- the tick -----------------------------------------------------------------------------------------------------

    async def run(self, every_s: float) -> None:
        while True:
            try:
                await self.tick()
            except Exception:  # one bad tick must not stop following
                log.exception("following robots' routes failed")
            await asyncio.sleep(every_s)

    async def tick(self) -> None:
        now = self.clock()
        catalogue = await self._catalogue(now)
        live = [d for d in self.registry.live() if not d.deleted]
        for gone in set(self.routes) - {d.id for d in live}:
            self.routes.pop(gone, None)
            self._route_at.pop(gone, None)
        if not self._taken_back:
            self._take_back(live, now)
            self._taken_back = True
        needed: set[Key] = set()
        for deployment in live:
            route = self.routes.get(deployment.id)
            if not route:
                continue
            plan = plan_route(route, now, deployment.placement, deployment.arrived_at, self.policy)
            self.routes[deployment.id] = plan.route
            needed.update((deployment.app, pool) for pool in plan.warm)
            if plan.move_to is not None and not deployment.moving and not deployment.hedge:
                eta = next(w.eta for w in plan.route if w.pool == plan.move_to)
                why = f"its route: on {plan.move_to} in {eta - now:.1f} s"
                if self.move(deployment, plan.move_to, why):
                    self.routes[deployment.id] = tuple(w for w in plan.route if w.eta > eta)
        standby = {name: app.standby for name, app in catalogue.apps.items() if app.standby}
        single = [(d.app, d.placement) for d in live if not d.hedge]
        needed |= {key for key in standby_needs(single, standby, self.placements) if key[0] in catalogue.apps}
        await self._warm(needed, catalogue, now)

    def _take_back(self, live: Sequence[Deployment], now: float) -> None:
        """Follow on what a previous middleware recorded with its NetApps, which the registry took back at start:
        the routes' waypoints still ahead, and the warm holds (kept, no second warm-up, and released like any other
        once no robot needs them)."""
        for deployment in live:
            if deployment.id not in self.routes and ROUTE_META in deployment.meta:
                recorded = route_recorded(deployment.meta[ROUTE_META], now, self.placements, self.policy)
                if recorded:
                    self.routes[deployment.id] = recorded
                    log.info("deployment %s: its route taken back from before a restart", deployment.id)
        for key, instance in self.registry.holds().items():
            if key not in self.held:
                log.info("NetApp %s: a warm %s on %s taken back from before a restart", instance.name, *key)
                self.held[key] = instance

    async def _warm(self, needed: set[Key], catalogue: Catalogue, now: float) -> None:
        for key, instance in list(self.held.items()):
            if instance.state.phase == FAILED:  # held a broken one: let it go, a new one is started below
                await self._release(key, f"it failed: {instance.state.message}")
        plan = warm_plan(needed, self.held, self.idle_since, now, self.policy.idle_grace_s)
        self.idle_since = plan.idle_since
        for key in plan.release:
            await self._release(key, f"no robot of {key[0]} needed it for {self.policy.idle_grace_s:g} s")
        for app_name, placement in sorted(plan.start):
            app = catalogue.get(app_name)
            if app is None:
                continue
            try:
                instance = self.registry.hold(app, placement)
            except (QuotaExceeded, Unrunnable) as exc:
                log.warning("no warm %s on %s: %s", app_name, placement, exc)
                continue
            self.held[(app_name, placement)] = instance
            message = f"a warm {app_name} on {placement} for robots that may come"
            log.info("NetApp %s: %s", instance.name, message)
            self._untold[(app_name, placement)] = message
        for key, message in list(self._untold.items()):
            instance = self.held.get(key)
            if instance is None:
                del self._untold[key]
            elif instance.version > 0:  # the backend has it (an Event needs the NetApp to exist)
                del self._untold[key]
                await self.registry.backend.announce(instance.name, "Normal", WARMING, message)

    async def _release(self, key: Key, why: str) -> None:
        instance = self.held.pop(key)
        self.idle_since.pop(key, None)
        self._untold.pop(key, None)
        message = f"warm {key[0]} on {key[1]} released: {why}"
        log.info("NetApp %s: %s", instance.name, message)
        await self.registry.backend.announce(instance.name, "Normal", RELEASED, message)
        await self.registry.release_claim(warm_claim(*key), instance)

    async def close(self) -> None:
        """Keep the warm holds: they are recorded with their NetApps, so a restarted middleware takes them back (a
        backend whose netapps die with the middleware, the local one, stops them itself)."""
        self.held.clear()

    async def _catalogue(self, now: float) -> Catalogue:
        if self._apps is None or now - self._apps[0] >= CATALOGUE_EVERY_S:
            self._apps = (now, await asyncio.to_thread(self.catalogue))
        return self._apps[1]

    # -- what they cost ----------------------------------------------------------------------------------------------

    def standbys(self) -> dict[str, Any]:
        """Every warm netapp with what it costs: the CPU and memory it requests, and (local backend) its RSS."""
        apps = self._apps[1] if self._apps is not None else Catalogue()
        usage = getattr(self.registry.backend, "usage", None)  # the local backend's: its processes' RSS
        rows = []
        for (app_name, placement), instance in sorted(self.held.items()):
            app = apps.get(app_name)
            requests = (render_spec(app, placement).get("resources") or {}) if app is not None else {}
            rows.append(
                {
                    "app": app_name,
                    "placement": placement,
                    "netapp": instance.name,
                    "phase": instance.state.phase,
                    "url": instance.state.url,
                    "pool": instance.state.pool,
                    "robots": robot_claims(instance.claims),
                    "idleSince": self.idle_since.get((app_name, placement)),
                    "requests": {k: requests[k] for k in ("cpu", "memory") if k in requests},
                    **(usage(instance.name) if usage is not None else {}),
                }
            )
        total = sum(r.get("rssBytes", 0) for r in rows)
        return {"standbys": rows, "rssBytes": total, "routes": len(self.routes), "routesRefused": self.refused}
