"""The middleware's Prometheus metrics (GET /metrics): robots' own latency against their budgets, and deployments.

Read at scrape time from the registry and the switchover's latest reports (no state of its own). A robot's p95 and
budget here are what the robot measured and reported (`MiddlewareClient` with `budget_ms`), end to end: the link
included, which a netapp's own latency histogram cannot see. The chart's NetAppRobotLatencyOverBudget alert reads
them (charts/netapp-toolkit/files/rules.yaml).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from typing import Any

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector

from .services import Services

ROBOT_LABELS = ["robot", "deployment", "app", "placement", "netapp"]


class MiddlewareCollector(Collector):
    def __init__(self, services: Services) -> None:
        self.services = services

    def collect(self) -> Iterator[Any]:
        p95 = GaugeMetricFamily(
            "netapp_middleware_robot_latency_p95_seconds",
            "A robot's p95 latency on its netapp, as it last reported it (NaN: no result came back)",
            labels=ROBOT_LABELS,
        )
        budget = GaugeMetricFamily(
            "netapp_middleware_robot_budget_seconds", "A robot's latency budget (its deadline)", labels=ROBOT_LABELS
        )
        missed = GaugeMetricFamily(
            "netapp_middleware_robot_missed_per_second",
            "Frames a robot saw miss their deadline, per second, over its last report's window",
            labels=ROBOT_LABELS,
        )
        deployments: Counter[tuple[str, str]] = Counter()
        for d in self.services.registry.live():
            deployments[(d.app, d.placement or "auto")] += 1
            report = self.services.switchover.latest(d.id)
            if report is None:
                continue
            labels = [d.robot_id, d.id, d.app, d.placement or "auto", d.instance.name]
            p95.add_metric(labels, float("nan") if report.p95_ms is None else report.p95_ms / 1000)
            budget.add_metric(labels, report.deadline_ms / 1000)
            missed.add_metric(labels, report.missed / max(report.window_s, 1e-3))
        yield from (p95, budget, missed)
        count = GaugeMetricFamily("netapp_middleware_deployments", "Robots' deployments", labels=["app", "placement"])
        for (app, placement), n in sorted(deployments.items()):
            count.add_metric([app, placement], n)
        yield count


def render(services: Services) -> bytes:
    registry = CollectorRegistry()
    registry.register(MiddlewareCollector(services))
    return generate_latest(registry)
