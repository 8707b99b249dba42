"""The operator's side of the chart's rules and dashboards against real programs: `netapp operator` runs against the
Kubernetes emulator with a pool that has a ready node and one that has none, and a NetApp no kubelet ever starts;
Debian's Prometheus scrapes the operator's /metrics; NetAppNodePoolNoReadyNodes and NetAppNotReady fire in a real
Alertmanager for exactly those; every control-plane panel that reads the operator returns series."""

from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path

import pytest

from netapp.serve_process import free_port
from tests.monitoring.monitoring_helpers import dashboard_queries, program, render_rules, short_rules
from tests.monitoring.prometheus_stack import Webhook, alertmanager, notified, prometheus
from tests.operator.op_helpers import eventually, netapp, node, nodepool, operator_command

pytestmark = pytest.mark.timeout(180)

RULES = short_rules()


async def test_the_operators_alerts_fire_for_what_is_wrong_and_its_panels_have_data(
    emulator, api, helm: Path, tmp_path: Path
) -> None:
    program("prometheus")
    program("prometheus-alertmanager")
    rules = render_rules(helm, tmp_path, RULES)
    await api.apply(node("edge-1", {"pool": "edge"}, address="192.168.1.10"))
    await api.apply(nodepool("edge", "edge", {"pool": "edge"}))
    await api.apply(nodepool("cloud", "cloud", {"pool": "cloud"}))  # selects no node: none ready
    await api.apply(netapp("det"))  # placed on edge; no kubelet here, so its Deployment never becomes available
    port = free_port()
    hook = Webhook()
    flags = (f"--metrics=http://127.0.0.1:{port}/metrics", "--check-interval=0.5", "--liveness=")
    async with operator_command(str(emulator.url), tmp_path, *flags) as proc:

        async def placed():
            assert proc.returncode is None, (await proc.stdout.read()).decode()[-2000:]
            return ((await api.get("NetApp", "default", "det") or {}).get("status") or {}).get("url")

        await eventually(placed, timeout=60, what="the NetApp placed")
        # Prometheus, the Alertmanager and the waits block: in threads, so the emulator on this loop keeps serving.
        with contextlib.ExitStack() as stack:
            am = await asyncio.to_thread(stack.enter_context, alertmanager(tmp_path, hook.url))
            jobs = {"operator": [(f"127.0.0.1:{port}", {"namespace": "netapp-system", "pod": "operator-0"})]}
            prom = await asyncio.to_thread(stack.enter_context, prometheus(tmp_path, jobs, rules, am))
            stack.callback(hook.close)
            pool = await asyncio.to_thread(
                hook.wait_for, notified("NetAppNodePoolNoReadyNodes", "firing"), 60, "the pool alert"
            )
            assert {a["labels"]["pool"] for a in pool["alerts"] if a["status"] == "firing"} == {"cloud"}
            ready = await asyncio.to_thread(hook.wait_for, notified("NetAppNotReady", "firing"), 60, "NetAppNotReady")
            [alert] = ready["alerts"]
            assert (alert["labels"]["netapp"], alert["labels"]["severity"]) == ("det", "critical")
            empty = [
                f"{board} / {panel}: {expr}"
                for board, panel, expr in dashboard_queries()
                if "netapp_operator_" in expr and not await asyncio.to_thread(prom.query, expr)
            ]
            assert not empty, "\n".join(empty)
