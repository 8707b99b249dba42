"""The switchover loop around `decision.decide`: keeps each robot's latency reports, moves a robot make-before-break
when the decision says so, and tells why (Kubernetes Events through the backend, the deployment's `history` and
`message`, the log). When the decision says a cold move is coming (`Decision.prepare`), it starts the target's
netapp at once (`Following.prepare`) and decides again the moment that one is Ready, not at the robot's next
report. Runs on the event loop, like the registry."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

from ..backends.base import FAILED, READY
from ..catalogue import Catalogue
from ..deployments import Deployment, QuotaExceeded, Registry
from ..instances import Instance
from .ahead import AheadPolicy
from .decision import MOVE_FAILED, MOVED, STAY_NO_BETTER, Decision, Report, SwitchPolicy, decide
from .following import Following

log = logging.getLogger(__name__)

MOVING = "Moving"
STALE = "StaleReport"
HEDGED = "Hedged"
REPORTS_KEPT = 64  # per deployment, on its current placement: more than sustain_s needs at any sane rate
HISTORY_KEPT = 16


class TooFrequent(Exception):
    """A robot reported again sooner than `min_interval_s` after its last report."""


class Switchover:
    """Latency reports in, moves out; see the module docstring."""

    def __init__(
        self,
        registry: Registry,
        catalogue: Callable[[], Catalogue],
        placements: Sequence[str] = ("edge", "cloud"),
        policy: SwitchPolicy | None = None,
        *,
        ready_timeout_s: float = 180.0,
        drain_s: float = 10.0,
        min_interval_s: float = 0.2,
        clock: Callable[[], float] = time.time,
        ahead: AheadPolicy | None = None,
        tick_s: float = 0.2,
    ) -> None:
        self.registry = registry
        self.catalogue = catalogue
        self.placements = list(placements)
        self.policy = policy or SwitchPolicy()
        self.ready_timeout_s = ready_timeout_s
        # Make before break: the old NetApp serves until the robot reports from the new one, or this long.
        self.drain_s = drain_s
        self._arrived: dict[str, tuple[str, asyncio.Event]] = {}  # deployment -> (its new URL, the robot is there)
        self.min_interval_s = min_interval_s
        self.clock = clock
        self._reports: dict[str, deque[Report]] = {}
        self._measured: dict[str, dict[str, Report]] = {}
        self._last: dict[str, tuple[float, str]] = {}  # deployment -> (when it last reported, last decision)
        self._tasks: set[asyncio.Task[None]] = set()
        self._preparing: set[str] = set()  # deployments waiting on a netapp started ahead of their move
        # Robots' routes and the catalogue's warm standbys, ticking every tick_s once `start`ed.
        self.following = Following(
            registry, catalogue, self.placements, ahead or AheadPolicy(), self._route_move, clock=clock
        )
        self.tick_s = tick_s

    def start(self) -> None:
        """Follow routes and keep standbys warm (on the running event loop) until `close`."""
        self._spawn(self.following.run(self.tick_s))

    @property
    def enabled(self) -> bool:
        return len(self.placements) > 1

    def report(
        self,
        deployment: Deployment,
        p95_ms: float | None,
        deadline_ms: float,
        missed: int,
        window_s: float,
        url: str | None = None,
    ) -> Decision:
        """Take one report of the robot's (measured on `url`, where given); start a move when one is due. Raises
        TooFrequent."""
        now = self.clock()
        self._prune()
        last_at, last_reason = self._last.get(deployment.id, (float("-inf"), ""))
        if now - last_at < self.min_interval_s:
            raise TooFrequent(f"at most one report per {self.min_interval_s:g} s")
        arrived = self._arrived.get(deployment.id)
        if arrived is not None and url is not None and url.rstrip("/") == arrived[0].rstrip("/"):
            arrived[1].set()  # the robot is on its new netapp: the old one may go
        current = deployment.instance.state.url
        if url is not None and current is not None and url.rstrip("/") != current.rstrip("/"):
            # Measured on a netapp the robot is leaving (a move or a failover it has not followed yet).
            self._last[deployment.id] = (now, STALE)
            return Decision(None, STALE, f"measured on {url}, not on the deployment's {current}: ignored")
        placement = deployment.placement or "auto"
        report = Report(now, placement, p95_ms, deadline_ms, missed, window_s)
        reports = self._reports.setdefault(deployment.id, deque(maxlen=REPORTS_KEPT))
        reports.append(report)
        self._measured.setdefault(deployment.id, {})[placement] = report
        decision = self._decide(deployment, now, list(reports))
        self._last[deployment.id] = (now, decision.reason)
        if decision.move_to is not None:
            deployment.moving = True  # at once: the next report must not start a second move
            self._spawn(self._move(deployment, decision, started=now))
        elif decision.prepare is not None and deployment.reuse:  # the move will claim the shared netapp started now
            until = now + self.policy.sustain_s + self.policy.trend_window_s  # each such report pushes it on
            if deployment.id in self._preparing:
                self.following.prepared[(deployment.app, decision.prepare)] = until
            else:
                self._preparing.add(deployment.id)
                self._spawn(self._prepare(deployment, decision.prepare, until))
        if decision.reason == STAY_NO_BETTER and last_reason != STAY_NO_BETTER:
            log.info("deployment %s stays: %s", deployment.id, decision.message)
            self._spawn(
                self.registry.backend.announce(deployment.instance.name, "Warning", decision.reason, decision.message)
            )
        return decision

    def _decide(self, deployment: Deployment, now: float, reports: list[Report]) -> Decision:
        if deployment.moving:
            return Decision(None, MOVING, "a switchover is under way")
        if deployment.hedge:
            return Decision(None, HEDGED, "a hedged deployment is on several placements already")
        if not self.enabled:
            return Decision(None, "Disabled", "switchover needs two placements (--switchover-placements)")
        return decide(
            now,
            deployment.placement or "auto",
            deployment.arrived_at,
            reports,
            self._measured[deployment.id],
            self.placements,
            self.policy,
            self.registry.warm_placements(deployment.app) if deployment.reuse else (),
        )

    async def _prepare(self, deployment: Deployment, placement: str, until: float) -> None:
        """Start a netapp on `placement` ahead of the robot's move; once it is Ready, decide again on the robot's
        latest reports (a move into it is a warm one now) rather than at its next report."""
        try:
            instance = await self.following.prepare(deployment.app, placement, until)
            if instance is None or not await self._ready(instance, deployment):
                return
            reports = self._reports.get(deployment.id)
            here = deployment.placement or "auto"
            if not reports or deployment.moving or deployment.deleted or reports[-1].placement != here:
                return  # moved (the sustained breach came first), gone, or reporting from elsewhere
            now = self.clock()
            decision = self._decide(deployment, now, list(reports))
            if decision.move_to is not None:
                deployment.moving = True
                await self._move(deployment, decision, started=now)
        finally:
            self._preparing.discard(deployment.id)

    async def _ready(self, instance: Instance, deployment: Deployment) -> bool:
        """Wait until `instance` is Ready (True), or failed, timed out, or the robot left or is moving (False)."""
        deadline = asyncio.get_running_loop().time() + self.ready_timeout_s
        while instance.state.phase != READY or not instance.state.url:
            remaining = deadline - asyncio.get_running_loop().time()
            if instance.state.phase == FAILED or remaining <= 0 or deployment.deleted or deployment.moving:
                return False
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(instance.changed.wait(), min(remaining, 1.0))
        return True

    def latest(self, deployment_id: str) -> Report | None:
        """The robot's last report on its current placement (its /metrics read it), or None."""
        reports = self._reports.get(deployment_id)
        return reports[-1] if reports else None

    async def close(self) -> None:
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.wait(list(self._tasks))
        await self.following.close()

    def _route_move(self, deployment: Deployment, placement: str, why: str) -> bool:
        """Move a robot where its route takes it (make before break, as any move); False when it cannot now."""
        if deployment.moving or deployment.hedge or deployment.deleted:
            return False
        deployment.moving = True  # at once: the next tick must not start a second move
        now = self.clock()
        self._spawn(self._move(deployment, Decision(placement, MOVED, why), started=now))
        return True

    async def _move(self, deployment: Deployment, decision: Decision, started: float) -> None:
        target = str(decision.move_to)
        source, old = deployment.placement, deployment.instance
        app = (await asyncio.to_thread(self.catalogue)).get(deployment.app)  # a source may read a file
        if app is None:
            deployment.moving = False
            deployment.note = f"not moved: {deployment.app} is no longer in the catalogue"
            return
        log.warning("deployment %s of robot %s: %s", deployment.id, deployment.robot_id, decision.message)
        deployment.note = f"switching over to {target}: {decision.message}"
        await self.registry.backend.announce(old.name, "Warning", "SwitchingOver", decision.message)
        deployment.moving = False  # Registry.move sets it for the duration of the move
        try:
            moved = await self.registry.move(deployment, app, target, self.ready_timeout_s)
        except (ValueError, QuotaExceeded) as exc:
            deployment.note = f"not moved to {target}: {exc}"
            log.warning("deployment %s not moved: %s", deployment.id, exc)
            return
        entry: dict[str, Any] = {
            "at": self.clock(),
            "from": source,
            "to": target,
            "reason": MOVED if moved else MOVE_FAILED,
            "message": decision.message,
            "seconds": round(self.clock() - started, 2),
        }
        if moved is None:
            deployment.note = f"switchover to {target} failed: the new NetApp was not Ready; staying on {source}"
            log.warning("deployment %s: %s", deployment.id, deployment.note)
            await self.registry.backend.announce(old.name, "Warning", MOVE_FAILED, deployment.note)
        else:
            new = deployment.instance
            entry.update(url=new.state.url, pool=new.state.pool, netapp=new.name)
            deployment.note = f"moved from {source} to {target} in {entry['seconds']:.1f} s: {decision.message}"
            self._reports.pop(deployment.id, None)  # a fresh start on the new placement
            log.warning("deployment %s: %s", deployment.id, deployment.note)
            deployment.history = [*deployment.history, entry][-HISTORY_KEPT:]
            arrived = asyncio.Event()
            self._arrived[deployment.id] = (str(new.state.url), arrived)
            await self.registry.backend.announce(new.name, "Normal", MOVED, deployment.note)
            await self._release_when_moved(deployment, moved, arrived)
            return
        deployment.history = [*deployment.history, entry][-HISTORY_KEPT:]

    async def _release_when_moved(self, deployment: Deployment, old: Any, arrived: asyncio.Event) -> None:
        """Release the old NetApp once the robot reports from its new URL (`arrived`), or after `drain_s` (a robot
        that does not report, or went away)."""
        try:
            await asyncio.wait_for(arrived.wait(), self.drain_s)
            log.info("deployment %s: the robot reports from its new netapp; releasing %s", deployment.id, old.name)
        except asyncio.TimeoutError:
            log.info(
                "deployment %s: no report from its new netapp in %.0f s; releasing %s",
                deployment.id,
                self.drain_s,
                old.name,
            )
        finally:
            self._arrived.pop(deployment.id, None)
            await self.registry.release(deployment, old)

    def _prune(self) -> None:
        """Forget deleted deployments' reports."""
        for deployment_id in [d for d in self._last if not self.registry.exists(d)]:
            self._last.pop(deployment_id, None)
            self._reports.pop(deployment_id, None)
            self._measured.pop(deployment_id, None)
            self._arrived.pop(deployment_id, None)

    def _spawn(self, coro: Any) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
