"""The chart's rules and dashboards against real programs: Debian's Prometheus scrapes a real `netapp serve`
(YOLOX-Nano, deployed by the real middleware) and the middleware; robots overload the netapp; the latency alert fires
in a real Alertmanager, which notifies a webhook here, and resolves once the load stops; then every dashboard query
about netapps, robots and the middleware returns series from that Prometheus (the operator's: test_control_plane.py).

The rules are the chart's own (files/rules.yaml, rendered by helm) with short windows and `for:` durations."""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
import requests
from netapp_middleware.backends.local import LocalBackend

from netapp.client.middleware import MiddlewareClient
from netapp.client.netapp_client import NetAppClient
from tests.middleware.mw_helpers import ROBOTS
from tests.monitoring.monitoring_helpers import dashboard_queries, program, render_rules, short_rules
from tests.monitoring.prometheus_stack import Webhook, alertmanager, notified, prometheus

pytestmark = pytest.mark.timeout(240)

ALERT = "NetAppLatencyHigh"
# 50 ms: twice a lone robot's p95 here (about 25 ms); robots waiting for each other's frames wait longer.
RULES = short_rules(latencyP95Seconds=0.05)
ROBOT_COUNT = 12  # each sends 15 frames a second: three times what one inference thread serves here, and more
SEND_EVERY_S = 1 / 15
# One batch of one frame at a time on one thread: the netapp's capacity is one YOLOX-Nano inference after another.
NETAPP = [sys.executable, "-m", "netapp", "serve", "--max-batch", "1", "--lanes", "1", "--threads", "1"]


def _stream(client: NetAppClient, jpeg: bytes, stop: threading.Event) -> None:
    while not stop.is_set():
        client.send(jpeg)
        stop.wait(SEND_EVERY_S)  # the robot's frame rate, not a synchronisation


def test_an_overloaded_netapp_fires_the_latency_alert_which_resolves_and_the_panels_have_data(
    helm: Path, tmp_path: Path, start_middleware: Any, real_model_path: Path, jpeg: bytes
) -> None:
    program("prometheus")
    program("prometheus-alertmanager")
    rules = render_rules(helm, tmp_path, RULES)
    backend = LocalBackend(model=str(real_model_path), command=NETAPP, ready_timeout_s=60)
    # One placement: a robot over its budget stays (no switchover starts a second netapp).
    server = start_middleware(backend, switchover={"placements": ["edge"]})
    hook = Webhook()
    stop = threading.Event()
    clients: list[NetAppClient] = []
    senders: list[threading.Thread] = []
    try:
        with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw, alertmanager(tmp_path, hook.url) as am:
            edge = mw.deploy("object-detection", placement="edge", timeout=60)
            name = mw.status(edge)["netapp"]
            jobs = {
                "netapps": [(urlsplit(edge.url).netloc, {"namespace": "robots", "netapp": name, "pool": "edge"})],
                "middleware": [(urlsplit(server.url).netloc, {"namespace": "netapp-system"})],
            }
            with prometheus(tmp_path, jobs, rules, am) as prom:
                # A frame refused (no session): what the refusal panels show.
                assert requests.post(f"{edge.url}/send_image", data=b"not a frame", timeout=10).status_code == 404
                # The robots: one reports its latency against a 50 ms budget to the middleware, all stream.
                clients.append(mw.netapp_client(edge, budget_ms=50, report_every_s=0.5, transport="ws"))
                # The others without pacing (a robot's client holds frames back while the netapp is the bottleneck).
                clients += [
                    NetAppClient(edge.url, token=edge.token, transport="ws", pacing=False)
                    for _ in range(ROBOT_COUNT - 1)
                ]
                for c in clients:
                    c.__enter__()
                    senders.append(threading.Thread(target=_stream, args=(c, jpeg, stop), daemon=True))
                    senders[-1].start()
                started = time.monotonic()
                try:
                    firing = hook.wait_for(notified(ALERT, "firing"), 90, f"{ALERT} firing")
                except AssertionError as exc:  # what Prometheus saw, to tell a slow machine from a broken rule
                    seen = {e: prom.query(e) for e in ("up", "netapp:netapp_latency_seconds:p95")}
                    raise AssertionError(f"{exc}\nPrometheus: {seen}") from exc
                [alert] = [a for a in firing["alerts"] if a["labels"]["alertname"] == ALERT]
                assert alert["labels"]["netapp"] == name and alert["labels"]["severity"] == "warning"
                assert alert["annotations"]["runbook_url"].endswith("operating.md#netapplatencyhigh")
                [p95] = prom.query(f'netapp:netapp_latency_seconds:p95{{netapp="{name}"}}')
                fired_s = time.monotonic() - started
                stop.set()
                for t in senders:
                    t.join(10)
                for c in clients:
                    c.close()
                stopped = time.monotonic()
                resolved = hook.wait_for(notified(ALERT, "resolved"), 90, f"{ALERT} resolved")
                assert any(a["labels"].get("netapp") == name for a in resolved["alerts"])
                resolved_s = time.monotonic() - stopped
                # Every panel's query (but the operator's) returns series from what was scraped.
                empty = [
                    f"{board} / {panel}: {expr}"
                    for board, panel, expr in dashboard_queries()
                    if "netapp_operator_" not in expr and not prom.query(expr)
                ]
                assert not empty, "\n".join(empty)
        p95_ms = float(p95["value"][1]) * 1000
        print(f"p95 overloaded {p95_ms:.0f} ms; fired after {fired_s:.1f} s of load, resolved {resolved_s:.1f} s after")
    finally:
        stop.set()
        for c in clients:
            c.close()
        hook.close()
