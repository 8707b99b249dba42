"""`netapp operator` as a real process: logs in through a kubeconfig, serves its liveness probe and metrics,
reconciles."""

from __future__ import annotations

import aiohttp
import pytest

from netapp.serve_process import free_port
from tests.operator.op_helpers import eventually, netapp, node, nodepool, operator_command

pytestmark = pytest.mark.timeout(120)


async def test_netapp_operator_command(emulator, api, tmp_path):
    port, metrics_port = free_port(), free_port()
    flags = (
        f"--liveness=http://127.0.0.1:{port}/healthz",
        f"--metrics=http://127.0.0.1:{metrics_port}/metrics",
        "--check-interval=0.5",
    )
    async with operator_command(str(emulator.url), tmp_path, *flags) as proc:
        await api.apply(node("edge-1", {"pool": "edge"}, address="192.168.1.10"))
        await api.apply(nodepool("edge", "edge", {"pool": "edge"}))
        await api.apply(netapp("det"))

        async def url():
            if proc.returncode is not None:
                raise AssertionError(f"the operator exited: {(await proc.stdout.read()).decode()[-2000:]}")
            na = await api.get("NetApp", "default", "det")
            return ((na or {}).get("status") or {}).get("url")

        assert (await eventually(url, timeout=60, what="status.url")).startswith("http://192.168.1.10:")

        async def live():
            try:
                async with aiohttp.ClientSession() as s, s.get(f"http://127.0.0.1:{port}/healthz") as r:
                    return r.status == 200
            except aiohttp.ClientError:
                return False

        await eventually(live, timeout=30, what="the liveness endpoint")

        async def metrics():
            async with aiohttp.ClientSession() as s, s.get(f"http://127.0.0.1:{metrics_port}/metrics") as r:
                return await r.text()

        # What the chart's alerts read (charts/netapp-toolkit/files/rules.yaml): the pool's nodes, a reconcile.
        text = await metrics()
        assert 'netapp_operator_nodepool_ready_nodes{pool="edge",type="edge"} 1.0' in text
        assert 'netapp_operator_reconciles_total{result="ok"}' in text
        assert 'netapp_operator_netapp_ready{namespace="default",netapp="det"}' in text
