"""The operator against a real cluster. Opt in with KUBECONFIG=<file> NETAPP_E2E_CLUSTER=1 (it creates the CRDs,
a NodePool `e2e-pool` over every Linux node, and a temporary namespace, and removes what it created).
NETAPP_E2E_IMAGE picks the netapp image; NETAPP_E2E_WAIT_READY=1 also waits for the pods to become Ready."""

from __future__ import annotations

import asyncio
import os
import uuid
from collections.abc import AsyncIterator
from typing import Any

import pytest
from netapp_operator.config import OperatorConfig
from netapp_operator.kube import ApiError, Kube, login_from_info

from tests.operator.op_helpers import condition, eventually, netapp, nodepool
from tests.support.kube_emulator import load_crds

pytestmark = [
    pytest.mark.cluster,
    pytest.mark.timeout(600),
    pytest.mark.skipif(
        not (os.environ.get("KUBECONFIG") and os.environ.get("NETAPP_E2E_CLUSTER") == "1"),
        reason="real-cluster test: set KUBECONFIG and NETAPP_E2E_CLUSTER=1 to run it",
    ),
]
CRD_PATH = "/apis/apiextensions.k8s.io/v1/customresourcedefinitions"


@pytest.fixture
async def cluster() -> AsyncIterator[tuple[Kube, Any]]:
    import kopf

    info = kopf.login_with_kubeconfig(settings=kopf.OperatorSettings())

    async def login() -> Any:
        return await login_from_info(info)

    kube = Kube(login, manager="netapp-e2e")
    for crd in load_crds():
        await kube.request(
            "PATCH",
            f"{CRD_PATH}/{crd['metadata']['name']}",
            crd,
            params={"fieldManager": "netapp-e2e", "force": "true"},
            content_type="application/apply-patch+yaml",
        )

    async def established() -> bool:
        for crd in load_crds():
            got = await kube.request("GET", f"{CRD_PATH}/{crd['metadata']['name']}")
            if condition(got, "Established").get("status") != "True":
                return False
        return True

    await eventually(established, timeout=60, what="the CRDs to be established")
    yield kube, info
    await kube.close()


async def test_netapp_on_a_real_cluster(cluster):
    import kopf
    from netapp_operator.handlers import register

    kube, info = cluster
    namespace = f"netapp-e2e-{uuid.uuid4().hex[:6]}"
    await kube.request(
        "POST", "/api/v1/namespaces", {"apiVersion": "v1", "kind": "Namespace", "metadata": {"name": namespace}}
    )
    registry = kopf.OperatorRegistry()
    register(registry, OperatorConfig(namespaces=(namespace,), check_interval_seconds=1), connection=info)
    stop = asyncio.Event()
    tasks = await kopf.spawn_tasks(
        registry=registry, settings=kopf.OperatorSettings(), namespaces=[namespace], standalone=True, stop_flag=stop
    )
    runner = asyncio.ensure_future(asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED))
    try:
        await kube.apply(nodepool("e2e-pool", "edge", {"kubernetes.io/os": "linux"}))
        image = os.environ.get("NETAPP_E2E_IMAGE", "ghcr.io/netapp-toolkit/netapp:0.1.0")
        await kube.apply(netapp("e2e", namespace=namespace, image=image))

        async def placed() -> dict | None:
            na = await kube.get("NetApp", namespace, "e2e")
            return na if (na.get("status") or {}).get("url") else None

        na = await eventually(placed, timeout=120, what="status.url")
        assert na["status"]["pool"] == "e2e-pool"
        dep = await kube.get("Deployment", namespace, "e2e-e2e-pool")
        assert dep["metadata"]["ownerReferences"][0]["uid"] == na["metadata"]["uid"]
        if os.environ.get("NETAPP_E2E_WAIT_READY") == "1":

            async def ready() -> bool:
                got = await kube.get("NetApp", namespace, "e2e")
                return condition(got, "Ready").get("status") == "True"

            await eventually(ready, timeout=400, interval=2, what="Ready")
        await kube.delete("NetApp", namespace, "e2e")

        async def collected() -> bool:
            return await kube.get("Deployment", namespace, "e2e-e2e-pool") is None

        await eventually(collected, timeout=120, interval=1, what="garbage collection of the children")
    finally:
        stop.set()
        await asyncio.wait_for(runner, timeout=60)
        for t in tasks:
            t.cancel()
        for call in (
            kube.delete("NodePool", None, "e2e-pool"),
            kube.request("DELETE", f"/api/v1/namespaces/{namespace}"),
        ):
            try:
                await call
            except ApiError:
                pass
