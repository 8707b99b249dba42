"""kopf running the real handlers against the API emulator: create, update, delete, failover, malformed input."""

from __future__ import annotations

import base64
from typing import Any

import pytest

from tests.operator.op_helpers import (
    CLOUD,
    EDGE,
    condition,
    eventually,
    get_status,
    netapp,
    node,
    nodepool,
    setup_pools,
)

pytestmark = pytest.mark.timeout(120)


async def test_create_places_on_edge_and_sets_url(api, operator):
    await setup_pools(api)
    await api.apply(netapp("det"))

    async def placed():
        na = await api.get("NetApp", "default", "det")
        return na if (na.get("status") or {}).get("url") else None

    na = await eventually(placed, what="status.url")
    dep = await api.get("Deployment", "default", "det-edge")
    svc = await api.get("Service", "default", "det-edge")
    assert na["status"]["pool"] == "edge"
    assert na["status"]["url"] == f"http://192.168.1.10:{svc['spec']['ports'][0]['nodePort']}"
    assert dep["spec"]["template"]["spec"]["nodeSelector"] == EDGE
    key = (await api.get("Secret", "default", "det-cluster-key"))["data"]["key"]  # the replicas' shared key
    await api.apply(netapp("det", replicas=2))
    await eventually(lambda: _replicas_are(api, 2), what="the update")
    assert (await api.get("Secret", "default", "det-cluster-key"))["data"]["key"] == key  # made once, kept
    assert condition(na, "Placed")["status"] == "True"
    assert condition(na, "Ready")["status"] == "False"
    assert operator.alive


async def _replicas_are(api: Any, n: int) -> bool:
    dep = await api.get("Deployment", "default", "det-edge")
    return bool(dep) and dep["spec"].get("replicas") == n


async def events_for(api: Any, name: str, namespace: str = "default") -> list[dict[str, Any]]:
    result = await api.request("GET", f"/api/v1/namespaces/{namespace}/events")
    return [e for e in result.get("items", []) if e.get("involvedObject", {}).get("name") == name]


async def test_ready_follows_available_replicas(api, operator):
    await setup_pools(api)
    await api.apply(netapp("det", replicas=2))
    await eventually(lambda: api.get("Deployment", "default", "det-edge"), what="the Deployment")

    # Pods crash-loop: they exist but are never available.
    await api.patch_status(
        "Deployment",
        "default",
        "det-edge",
        {"replicas": 2, "readyReplicas": 0, "availableReplicas": 0, "unavailableReplicas": 2},
    )

    async def deploying():
        s = await get_status(api, "det")
        return s if s.get("phase") == "Deploying" and s.get("url") else None

    status = await eventually(deploying, what="phase Deploying")
    assert condition({"status": status}, "Ready")["reason"] == "ReplicasUnavailable"

    await api.patch_status(
        "Deployment",
        "default",
        "det-edge",
        {"replicas": 2, "readyReplicas": 2, "availableReplicas": 2, "unavailableReplicas": 0},
    )

    async def ready():
        s = await get_status(api, "det")
        return s if s.get("phase") == "Ready" else None

    status = await eventually(ready, what="phase Ready")
    assert status["readyReplicas"] == 2
    assert condition({"status": status}, "Ready")["status"] == "True"


async def test_update_patches_children(api, operator):
    await setup_pools(api)
    await api.apply(netapp("det", replicas=1, env=[{"name": "A", "value": "1"}]))
    await eventually(lambda: api.get("Deployment", "default", "det-edge"), what="the Deployment")
    await api.request(
        "PATCH",
        "/apis/netapp.dev/v1alpha1/namespaces/default/netapps/det",
        {
            "spec": {
                "image": "example.org/other:2",
                "replicas": 3,
                "autoscaling": None,
                "env": [{"name": "B", "value": "2"}],
            }
        },
        content_type="application/merge-patch+json",
    )

    async def patched():
        dep = await api.get("Deployment", "default", "det-edge")
        container = dep["spec"]["template"]["spec"]["containers"][0]
        return dep if container["image"] == "example.org/other:2" and dep["spec"]["replicas"] == 3 else None

    dep = await eventually(patched, what="the patched Deployment")
    assert dep["spec"]["template"]["spec"]["containers"][0]["env"][-1:] == [{"name": "B", "value": "2"}]

    async def observed():
        s = await get_status(api, "det")
        return s.get("observedGeneration") == 2

    await eventually(observed, what="observedGeneration 2")

    # Autoscaling on: an HPA appears; off again: it goes.
    await api.request(
        "PATCH",
        "/apis/netapp.dev/v1alpha1/namespaces/default/netapps/det",
        {"spec": {"autoscaling": {"minReplicas": 1, "maxReplicas": 4}}},
        content_type="application/merge-patch+json",
    )
    hpa = await eventually(lambda: api.get("HorizontalPodAutoscaler", "default", "det-edge"), what="the HPA")
    assert hpa["spec"]["maxReplicas"] == 4
    # KEDA instead: a ScaledObject on the netapps' robots appears and the HPA goes.
    keda = {"engine": "keda", "metric": "robotsPerReplica", "prometheusAddress": "http://prometheus:9090"}
    await api.request(
        "PATCH",
        "/apis/netapp.dev/v1alpha1/namespaces/default/netapps/det",
        {"spec": {"autoscaling": keda}},
        content_type="application/merge-patch+json",
    )
    scaled = await eventually(lambda: api.get("ScaledObject", "default", "det-edge"), what="the ScaledObject")
    assert scaled["spec"]["triggers"][0]["type"] == "prometheus" and scaled["spec"]["maxReplicaCount"] == 4

    async def hpa_replaced():
        return await api.get("HorizontalPodAutoscaler", "default", "det-edge") is None

    await eventually(hpa_replaced, what="the HPA to give way to the ScaledObject")
    await api.request(
        "PATCH",
        "/apis/netapp.dev/v1alpha1/namespaces/default/netapps/det",
        {"spec": {"autoscaling": None}},
        content_type="application/merge-patch+json",
    )

    async def scaled_gone():
        return await api.get("ScaledObject", "default", "det-edge") is None

    await eventually(scaled_gone, what="the ScaledObject to be removed")

    async def hpa_gone():
        return await api.get("HorizontalPodAutoscaler", "default", "det-edge") is None

    await eventually(hpa_gone, what="the HPA to be removed")


async def test_delete_leaves_no_children(api, operator):
    await setup_pools(api)
    await api.apply(netapp("det"))
    dep = await eventually(lambda: api.get("Deployment", "default", "det-edge"), what="the Deployment")
    na = await api.get("NetApp", "default", "det")
    for child in (dep, await api.get("Service", "default", "det-edge")):
        [ref] = child["metadata"]["ownerReferences"]
        assert (ref["kind"], ref["name"], ref["uid"], ref["controller"]) == (
            "NetApp",
            "det",
            na["metadata"]["uid"],
            True,
        )
    assert not na["metadata"].get("finalizers")  # deletion never waits for the operator
    await api.delete("NetApp", "default", "det")

    async def gone():
        return (
            await api.get("Deployment", "default", "det-edge") is None
            and await api.get("Service", "default", "det-edge") is None
        )

    await eventually(gone, what="children to be garbage-collected")
    assert operator.alive


async def test_pool_failure_fails_over_to_cloud(api, operator):
    await setup_pools(api)
    await api.apply(netapp("det"))

    async def on_edge():
        s = await get_status(api, "det")
        return s.get("pool") == "edge" and s.get("url")

    await eventually(on_edge, what="placement on edge")
    await api.patch_status("Node", None, "edge-1", {"conditions": [{"type": "Ready", "status": "False"}]})

    async def on_cloud():
        s = await get_status(api, "det")
        return s if s.get("pool") == "cloud" else None

    status = await eventually(on_cloud, timeout=45, what="failover to cloud")
    assert status["url"] == "https://det.default.cloud.example.com"
    placed = condition({"status": status}, "Placed")
    assert (placed["status"], placed["reason"]) == ("True", "FailedOver")
    assert "edge" in placed["message"]
    dep = await api.get("Deployment", "default", "det-cloud")
    assert dep["spec"]["template"]["spec"]["nodeSelector"] == CLOUD
    assert dep["metadata"]["labels"]["netapp.dev/pool"] == "cloud"

    async def old_gone():
        return (
            await api.get("Deployment", "default", "det-edge") is None
            and await api.get("Service", "default", "det-edge") is None
        )

    await eventually(old_gone, what="the edge children to be removed")
    reasons = [e["reason"] for e in await events_for(api, "det")]
    assert "FailedOver" in reasons

    async def pool_status():
        np = await api.get("NodePool", None, "edge")
        return (np.get("status") or {}).get("totalNodes") == 1 and np["status"]["readyNodes"] == 0

    await eventually(pool_status, what="the edge NodePool's status")


async def test_no_eligible_pool_is_pending_until_one_appears(api, operator):
    await api.apply(netapp("det", placement={"policy": "edge", "requireGPU": True}))

    async def pending():
        s = await get_status(api, "det")
        return s if s.get("phase") == "Pending" else None

    status = await eventually(pending, what="phase Pending")
    placed = condition({"status": status}, "Placed")
    assert (placed["status"], placed["reason"]) == ("False", "NoEligiblePool")
    assert "GPU" in placed["message"]

    await api.apply(node("gpu-1", {"gpu": "yes"}))
    await api.apply(nodepool("edge-gpu", "edge", {"gpu": "yes"}, gpu=True))

    async def placed_on_gpu():
        s = await get_status(api, "det")
        return s.get("pool") == "edge-gpu"

    await eventually(placed_on_gpu, what="placement once a GPU pool exists")


async def test_malformed_netapps_get_conditions_and_others_still_work(api, operator):
    await setup_pools(api)
    bad = netapp("no-image")
    bad["spec"]["image"] = ""
    await api.apply(bad)
    await api.apply(netapp("negative", replicas=-1))
    await api.apply(netapp("lost", placement={"pool": "nowhere"}))
    await api.apply(netapp("good"))

    async def phase(name: str, want: str):
        s = await get_status(api, name)
        return s if s.get("phase") == want else None

    for name, want_phase, want_reason, text in [
        ("no-image", "Failed", "InvalidSpec", "spec.image"),
        ("negative", "Failed", "InvalidSpec", "spec.replicas"),
        ("lost", "Pending", "PoolNotFound", "nowhere"),
    ]:
        status = await eventually(
            lambda name=name, want_phase=want_phase: phase(name, want_phase), what=f"{name} phase {want_phase}"
        )
        placed = condition({"status": status}, "Placed")
        assert placed["reason"] == want_reason and text in placed["message"], placed

        async def warned(name=name, want_reason=want_reason):
            return any(e["type"] == "Warning" and e["reason"] == want_reason for e in await events_for(api, name))

        await eventually(warned, what=f"a Warning event for {name}")
        assert await api.get("Deployment", "default", f"{name}-edge") is None

    await eventually(lambda: phase("good", "Deploying"), what="the valid NetApp to deploy")
    assert operator.alive


async def test_operator_requests_fit_its_least_privilege_rbac(api, operator, emulator):
    """Run create, update, autoscaling, failover and delete, then check that every request the operator made
    is allowed by the ClusterRole in manifests/ (and nothing there is unused cluster-admin style)."""
    from tests.operator.op_harness import denied_requests

    await setup_pools(api)
    await api.apply(netapp("det", autoscaling={"maxReplicas": 2}))
    await eventually(lambda: api.get("HorizontalPodAutoscaler", "default", "det-edge"), what="the HPA")
    # a NetApp with cameras: its replicas' account, and a Role on its Leases, which the operator may grant
    await api.apply(netapp("cam", replicas=2, sources=[{"name": "door", "url": "rtsp://10.0.0.5/s"}]))
    binding = await eventually(lambda: api.get("RoleBinding", "default", "cam-cameras"), what="the camera RBAC")
    assert binding["metadata"]["ownerReferences"][0]["name"] == "cam"
    for kind in ("ServiceAccount", "Role"):
        assert await api.get(kind, "default", "cam-cameras") is not None
    await api.patch_status("Node", None, "edge-1", {"conditions": [{"type": "Ready", "status": "False"}]})

    async def moved():
        return await api.get("HorizontalPodAutoscaler", "default", "det-edge") is None

    await eventually(moved, timeout=45, what="failover with the old HPA removed")
    await api.delete("NetApp", "default", "det")

    denied, role = denied_requests(emulator)
    assert not denied, f"the operator needs permissions its ClusterRole lacks: {denied}"
    assert all("*" not in r["verbs"] and "*" not in r["resources"] for r in role["rules"])


async def test_restarted_operator_keeps_placed_netapps_placed(api, emulator, operator_config):
    """NetApps that exist when the operator starts are resumed on their pool, never flapping to Pending."""
    import kmock

    from tests.operator.op_harness import running_operator

    await setup_pools(api)
    await api.apply(netapp("det"))
    async with running_operator(emulator, operator_config):
        first = await eventually(lambda: get_status(api, "det"), what="a status")
        first = await eventually(on_url := (lambda: _url(api)), what="status.url")
    async with running_operator(emulator, operator_config):
        await api.request(
            "PATCH",
            "/apis/netapp.dev/v1alpha1/namespaces/default/netapps/det",
            {"spec": {"replicas": 2}},
            content_type="application/merge-patch+json",
        )

        async def resumed():
            dep = await api.get("Deployment", "default", "det-edge")
            return dep["spec"]["replicas"] == 2

        await eventually(resumed, what="the second operator to reconcile")
        assert await on_url() == first
    history = emulator.objects[kmock.resource("netapp.dev/v1alpha1/netapps"), "default", "det"].history
    phases = [((v or {}).get("status") or {}).get("phase") for v in history]
    assert "Pending" not in phases, phases


async def _url(api: Any) -> str | None:
    return (await get_status(api, "det")).get("url")


async def test_load_balancer_url_appears_with_its_address(api, operator):
    await api.apply(node("cloud-1", CLOUD))
    await api.apply(nodepool("cloud", "cloud", CLOUD, access={"serviceType": "LoadBalancer"}))
    await api.apply(netapp("det", port=8000))
    svc = await eventually(lambda: api.get("Service", "default", "det-cloud"), what="the Service")
    assert svc["spec"]["type"] == "LoadBalancer"

    async def reported():  # the status patch follows the children's apply; under load it can lag behind
        status = await get_status(api, "det")
        return status if status.get("conditions") else None

    status = await eventually(reported, what="the NetApp's status")
    assert not status.get("url") and condition({"status": status}, "Ready")["status"] != "True"
    # The cloud's load balancer controller publishes an address: the URL follows without a NetApp change.
    await api.patch_status("Service", "default", "det-cloud", {"loadBalancer": {"ingress": [{"ip": "203.0.113.9"}]}})

    async def url():
        return (await get_status(api, "det")).get("url") == "http://203.0.113.9:8000"

    await eventually(url, what="the load balancer's URL")


async def test_token_secret_is_made_once_and_never_rotated(api, operator):
    await setup_pools(api)
    await api.apply(netapp("det", access={"requireToken": True}))
    secret = await eventually(lambda: api.get("Secret", "default", "det-token"), what="the token Secret")
    na = await api.get("NetApp", "default", "det")
    [ref] = secret["metadata"]["ownerReferences"]
    assert (ref["kind"], ref["name"], ref["uid"]) == ("NetApp", "det", na["metadata"]["uid"])
    token = secret["data"]["token"]
    assert len(base64.b64decode(token)) >= 32
    dep = await eventually(lambda: api.get("Deployment", "default", "det-edge"), what="the Deployment")
    [container] = dep["spec"]["template"]["spec"]["containers"]
    assert {"name": "NETAPP_TOKEN", "valueFrom": {"secretKeyRef": {"name": "det-token", "key": "token"}}} in container[
        "env"
    ]

    # A spec change re-applies every child; the Secret keeps its token (robots hold it).
    await api.request(
        "PATCH",
        "/apis/netapp.dev/v1alpha1/namespaces/default/netapps/det",
        {"spec": {"replicas": 3}},
        content_type="application/merge-patch+json",
    )

    async def rescaled():
        d = await api.get("Deployment", "default", "det-edge")
        return d if d["spec"]["replicas"] == 3 else None

    await eventually(rescaled, what="the re-applied Deployment")
    assert (await api.get("Secret", "default", "det-token"))["data"]["token"] == token
    # That the operator only creates Secrets (never reads one) is checked by the RBAC test above; the owner
    # reference (asserted above) removes the Secret with its NetApp, as test_delete_leaves_no_children shows.


async def test_a_standby_is_warmed_on_the_next_best_pool_shown_in_status_and_released(api, operator):
    await setup_pools(api)
    await api.apply(netapp("det", standby={"replicas": 1}, resources={"cpu": "500m", "memory": "1Gi"}))

    async def warm():
        s = await get_status(api, "det")
        return s.get("standby") if s.get("pool") == "edge" and s.get("standby") else None

    standby = await eventually(warm, what="status.standby")
    assert standby["pool"] == "cloud" and standby["url"] == "https://det.default.cloud.example.com"
    assert standby["replicas"] == 1 and standby["requests"] == {"cpu": "500m", "memory": "1Gi"}
    dep = await api.get("Deployment", "default", "det-cloud")
    assert dep["metadata"]["labels"]["netapp.dev/role"] == "standby" and dep["spec"]["replicas"] == 1
    assert dep["spec"]["template"]["spec"]["nodeSelector"] == CLOUD
    assert await api.get("Service", "default", "det-cloud") is not None
    assert await api.get("Deployment", "default", "det-edge") is not None  # the netapp itself stays on edge

    # Its pods come up: the status says the standby is ready.
    ready = {"replicas": 1, "readyReplicas": 1, "availableReplicas": 1}
    await api.patch_status("Deployment", "default", "det-cloud", ready)

    async def ready():
        s = await get_status(api, "det")
        return (s.get("standby") or {}).get("readyReplicas") == 1 and s["standby"]["ready"]

    await eventually(ready, what="the standby to be ready")
    warming = [e for e in await events_for(api, "det") if e["reason"] == "StandbyWarming"]
    assert (
        len(warming) == 1
        and "NodePool 'cloud': 1 replica(s), each requesting cpu 500m, memory 1Gi" in (warming[0]["message"])
    )

    await api.request(  # no standby any more
        "PATCH",
        "/apis/netapp.dev/v1alpha1/namespaces/default/netapps/det",
        {"spec": {"standby": None}},
        content_type="application/merge-patch+json",
    )

    async def released():
        s = await get_status(api, "det")
        gone = await api.get("Deployment", "default", "det-cloud") is None
        return gone and not s.get("standby") and await api.get("Service", "default", "det-cloud") is None

    await eventually(released, what="the standby's children to go")
    assert await api.get("Deployment", "default", "det-edge") is not None
    reasons = [e["reason"] for e in await events_for(api, "det")]
    assert reasons.count("StandbyWarming") == 1 and reasons.count("StandbyReleased") == 1
