"""The operator's Prometheus metrics (GET /metrics): what its cache and work queue hold, read at scrape time.

A collector rather than gauges kept up to date: NetApps' readiness and pools' nodes are already in the cache (kept
by the watches), so a scrape reads them there and nothing on the reconcile path pays for metrics. The alerts and
dashboards of the chart (charts/netapp-toolkit/files/) read these names.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from netapp_operator.cache import Cache
from netapp_operator.status import READY, find
from netapp_operator.workqueue import WorkQueue

PHASES = ("Pending", "Deploying", "Ready", "Failed")


def netapp_ready(body: Mapping[str, Any]) -> bool:
    """Whether a NetApp's status says Ready (its Ready condition is True)."""
    condition = find((body.get("status") or {}).get("conditions"), READY)
    return condition is not None and condition.get("status") == "True"


class OperatorCollector(Collector):
    """Reads the cache and the work queue (`queue()`: None before the operator has started) on each scrape."""

    def __init__(self, cache: Cache, queue: Callable[[], WorkQueue | None]) -> None:
        self.cache = cache
        self.queue = queue

    def collect(self) -> Iterator[Any]:
        ready = GaugeMetricFamily(
            "netapp_operator_netapp_ready",
            "1 when the NetApp's Ready condition is True",
            labels=["namespace", "netapp"],
        )
        phase = GaugeMetricFamily(
            "netapp_operator_netapp_phase", "1 for the NetApp's status.phase", labels=["namespace", "netapp", "phase"]
        )
        for (namespace, name), body in list(self.cache.netapps.items()):
            ready.add_metric([namespace or "", name], 1.0 if netapp_ready(body) else 0.0)
            current = (body.get("status") or {}).get("phase")
            for p in PHASES:
                phase.add_metric([namespace or "", name, p], 1.0 if current == p else 0.0)
        yield ready
        yield phase
        ready_nodes = GaugeMetricFamily(
            "netapp_operator_nodepool_ready_nodes", "Ready nodes of a NodePool", labels=["pool", "type"]
        )
        nodes = GaugeMetricFamily("netapp_operator_nodepool_nodes", "Nodes a NodePool selects", labels=["pool", "type"])
        for pool in self.cache.pools().values():
            ready_nodes.add_metric([pool.name, pool.type], pool.ready_nodes)
            nodes.add_metric([pool.name, pool.type], pool.total_nodes)
        yield ready_nodes
        yield nodes
        queue = self.queue()
        reconciles = CounterMetricFamily(
            "netapp_operator_reconciles",
            "NetApp reconciles finished, by result (error: raised, retried later)",
            labels=["result"],
        )
        reconciles.add_metric(["ok"], queue.completed if queue else 0)
        reconciles.add_metric(["error"], queue.failures if queue else 0)
        yield reconciles
        yield GaugeMetricFamily(
            "netapp_operator_queue_depth", "NetApps waiting to be reconciled", value=len(queue) if queue else 0
        )


def registry_for(cache: Cache, queue: Callable[[], WorkQueue | None]) -> CollectorRegistry:
    registry = CollectorRegistry()
    registry.register(OperatorCollector(cache, queue))
    return registry


def render(registry: CollectorRegistry) -> bytes:
    return generate_latest(registry)


async def serve(registry: CollectorRegistry, endpoint: str) -> Any:
    """Serve `registry` at `endpoint` (e.g. http://0.0.0.0:8082/metrics) on the running loop, as kopf serves its
    liveness probe; returns the aiohttp runner to `cleanup()`."""
    from urllib.parse import urlsplit

    from aiohttp import web

    url = urlsplit(endpoint)

    async def metrics(_: web.Request) -> web.Response:
        return web.Response(body=render(registry), headers={"Content-Type": CONTENT_TYPE_LATEST})

    app = web.Application()
    app.router.add_get(url.path or "/metrics", metrics)
    runner = web.AppRunner(app, access_log=None)
    await runner.setup()
    await web.TCPSite(runner, url.hostname or "0.0.0.0", url.port or 80).start()
    return runner
