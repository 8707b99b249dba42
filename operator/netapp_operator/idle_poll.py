"""The operator's idle poller (I/O over netapp_operator.idle): asks the pods of each NetApp with
`spec.scaling.idleToZero` how many robots they serve, and puts a NetApp to sleep once it served none, with every
pod ready, for that long.

Why /metrics: each netapp already publishes its robots there (`netapp_robots_per_replica`, its open sessions, the
gauge the autoscaler reads), it is open like /readyz, and the operator already reaches pods by IP (the rollout
poller); a heartbeat would need the netapp to know where the operator is, and the middleware does not know robots
that reach a NetApp without it. A pod that does not answer counts as serving robots: a netapp is put to sleep only
on its own word. A pod that is not ready yet (still starting, its model loading) resets the clock: a NetApp is never
scaled to zero while a pod starts.
"""

from __future__ import annotations

import asyncio
import datetime
import logging
import time
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

import aiohttp

from netapp_operator import idle, render, rollouts
from netapp_operator.cache import Cache, Key
from netapp_operator.kube import Kube
from netapp_operator.status import timestamp

logger = logging.getLogger(__name__)
MAX_METRICS_BYTES = 256 * 1024  # a netapp's /metrics is a few KiB
Announce = Callable[[Mapping[str, Any], str, str, str], Awaitable[None]]


class IdlePoller:
    def __init__(self, kube: Kube, cache: Cache, announce: Announce, timeout_s: float = 5.0) -> None:
        self.kube = kube
        self.cache = cache
        self.announce = announce
        self.timeout_s = timeout_s
        self._clocks: dict[Key, idle.QuietClock] = {}
        self._session: aiohttp.ClientSession | None = None

    def watched(self) -> list[Mapping[str, Any]]:
        """The awake, placed NetApps that may sleep; the clocks of the others are dropped."""
        found = []
        for key, netapp in list(self.cache.netapps.items()):
            spec = self.cache.specs.get(key)
            placed = (netapp.get("status") or {}).get("pool")
            if (
                spec is not None
                and not spec.problems
                and placed
                and idle.idle_after_s(spec)
                and not idle.asleep(netapp)
            ):
                found.append(netapp)
        keep = {(n["metadata"].get("namespace"), n["metadata"]["name"]) for n in found}
        for key in [k for k in self._clocks if k not in keep]:
            del self._clocks[key]
        return found

    async def close(self) -> None:
        if self._session is not None:
            await self._session.close()

    async def tick(self, netapp: Mapping[str, Any]) -> None:
        """One look at the NetApp's pods; it goes to sleep when it has been quiet long enough. Never raises."""
        meta = netapp["metadata"]
        key = (meta.get("namespace"), meta["name"])
        try:
            await self._look(key, netapp)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # an API server error: looked at again next tick, the clock kept
            logger.warning("idle check of NetApp %s/%s: %s", key[0], key[1], exc)

    async def _look(self, key: Key, netapp: Mapping[str, Any]) -> None:
        spec = self.cache.specs[key]
        after = idle.idle_after_s(spec)
        assert after is not None
        pool = netapp["status"]["pool"]
        labels = render.labels(key[1], pool)
        deployment = self.cache.deployments.get((key[0], render.child_name(key[1], pool))) or {}
        wanted = int((deployment.get("spec") or {}).get("replicas") or 0)
        pods = [p for p in await self.kube.list("Pod", key[0], labels) if _ours(p, labels)]
        all_ready = wanted > 0 and len(pods) == wanted and all(rollouts.pod_ready(p) for p in pods)
        robots = await self._robots(pods, int(spec.port), spec.tls is not None) if all_ready else None
        clock = self._clocks.setdefault(key, idle.QuietClock(wake=idle.wake_value(netapp)))
        quiet_s = clock.observe(time.monotonic(), idle.wake_value(netapp), all_ready, robots)
        if quiet_s < after:
            return
        now = datetime.datetime.now(datetime.timezone.utc)
        await self.kube.patch_status("NetApp", key[0], key[1], idle.idle_status(netapp, timestamp(now)))
        del self._clocks[key]
        logger.info("NetApp %s/%s: no robot for %.0f s: scaling it to zero", key[0], key[1], quiet_s)
        await self.announce(netapp, "Normal", "ScaledToZero", f"no robot for {quiet_s:.0f} s: 0 replicas until woken")

    async def _robots(self, pods: list[Mapping[str, Any]], port: int, tls: bool) -> float | None:
        """The robots the pods serve together; None when one of them did not say."""
        counts = await asyncio.gather(*(self._robots_of(rollouts.pod_url(p, port, tls)) for p in pods))
        return None if any(c is None for c in counts) else sum(c for c in counts if c is not None)

    async def _robots_of(self, url: str) -> float | None:
        if self._session is None:
            self._session = aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=self.timeout_s))
        try:  # a pod's certificate names its Service, not the pod's IP: not verified (as the rollout poller)
            async with self._session.get(url + "/metrics", ssl=False) as answer:
                text = (await answer.content.read(MAX_METRICS_BYTES)).decode(errors="replace")
                return idle.robots_in(text) if answer.status == 200 else None
        except (aiohttp.ClientError, asyncio.TimeoutError):
            return None


def _ours(pod: Mapping[str, Any], labels: Mapping[str, str]) -> bool:
    """A pod of the NetApp's Deployment (not its standby's), not going away."""
    meta = pod["metadata"]
    return not meta.get("deletionTimestamp") and all((meta.get("labels") or {}).get(k) == v for k, v in labels.items())
