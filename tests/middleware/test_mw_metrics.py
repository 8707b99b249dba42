"""The middleware's /metrics: a robot's reported p95 and budget, as the chart's NetAppRobotLatencyOverBudget alert
reads them (charts/netapp-toolkit/files/rules.yaml), open without a token like /healthz."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import requests
from netapp_middleware.backends.local import LocalBackend
from prometheus_client.parser import text_string_to_metric_families

from netapp.client.middleware import MiddlewareClient
from tests.middleware.mw_helpers import DEADLINE_S, ROBOTS


def _samples(url: str) -> dict[str, list[Any]]:
    reply = requests.get(f"{url}/metrics", timeout=10)
    assert reply.status_code == 200, reply.text
    return {f.name: f.samples for f in text_string_to_metric_families(reply.text)}


def test_a_robots_reported_latency_and_budget_are_metrics(start_middleware: Any, tiny_model_path: Path) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, switchover={"min_interval_s": 0.0})
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        view = mw.create("object-detection", placement="edge")
        before = _samples(server.url)
        assert before["netapp_middleware_robot_latency_p95_seconds"] == []  # nothing reported yet
        mw.report(view["id"], 250.0, 100.0, 6, 2.0)
        after = _samples(server.url)
    (p95,) = after["netapp_middleware_robot_latency_p95_seconds"]
    (budget,) = after["netapp_middleware_robot_budget_seconds"]
    (missed,) = after["netapp_middleware_robot_missed_per_second"]
    assert p95.value == 0.25 and budget.value == 0.1 and missed.value == 3.0
    assert p95.labels["robot"] == "robot-1" and p95.labels["deployment"] == view["id"]
    assert p95.labels["app"] == "object-detection" and p95.labels["placement"] == "edge"
    (count,) = after["netapp_middleware_deployments"]
    assert count.value == 1 and count.labels == {"app": "object-detection", "placement": "edge"}
