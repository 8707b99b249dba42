"""The watch cache keeps what placement and status read, and drops the bulk of each object."""

from __future__ import annotations

import asyncio

from netapp_operator import status
from netapp_operator.cache import Cache, slim
from netapp_operator.watches import Watches, gone_netapps

MANAGED_FIELDS = [{"manager": "kube-controller-manager", "fieldsV1": {"f:status": {"f:replicas": {}}}}] * 20


def deployment() -> dict:
    return {
        "apiVersion": "apps/v1",
        "kind": "Deployment",
        "metadata": {
            "name": "det-edge",
            "namespace": "robots",
            "generation": 3,
            "labels": {"app": "det"},
            "managedFields": MANAGED_FIELDS,
            "annotations": {"deployment.kubernetes.io/revision": "3"},
        },
        "spec": {"replicas": 2, "template": {"spec": {"containers": [{"name": "netapp", "image": "x"}]}}},
        "status": {"replicas": 2, "readyReplicas": 2, "updatedReplicas": 2, "availableReplicas": 2},
    }


def test_a_slim_deployment_reads_the_same_and_weighs_less():
    full = deployment()
    small = slim(full, "Deployment")
    assert "managedFields" not in small["metadata"] and "template" not in small["spec"]
    assert small["metadata"]["name"] == "det-edge" and small["metadata"]["generation"] == 3
    assert status.readiness(small, "http://x") == status.readiness(full, "http://x")
    assert len(repr(small)) < len(repr(full)) / 4


def test_a_netapp_keeps_its_whole_spec_and_drops_kopfs_copy():
    body = {
        "metadata": {
            "name": "det",
            "namespace": "robots",
            "generation": 1,
            "managedFields": MANAGED_FIELDS,
            "annotations": {"netapp.dev/last-handled-configuration": '{"spec": {"image": "x"}}'},
        },
        "spec": {"image": "x", "replicas": 1},
        "status": {"url": "http://a"},
    }
    cache = Cache()
    cache.on_netapp(body, deleted=False)
    cached = cache.netapps[("robots", "det")]
    assert cached["spec"] == body["spec"] and cached["status"] == body["status"]
    assert set(cached["metadata"]) == {"name", "namespace", "generation"}
    assert cache.specs[("robots", "det")].image == "x"


def test_a_slim_service_keeps_ports_and_load_balancer():
    svc = {
        "metadata": {"name": "det-edge", "namespace": "robots", "managedFields": MANAGED_FIELDS},
        "spec": {"type": "NodePort", "ports": [{"port": 5896, "nodePort": 30001}], "selector": {"a": "b"}},
        "status": {"loadBalancer": {"ingress": [{"ip": "1.2.3.4"}]}},
    }
    small = slim(svc, "Service")
    assert small["spec"] == {"type": "NodePort", "ports": [{"port": 5896, "nodePort": 30001}]}
    assert small["status"] == svc["status"]


def _versioned(body: dict, version: str, uid: str = "u1", **status: object) -> dict:
    return {**body, "metadata": {**body["metadata"], "resourceVersion": version, "uid": uid}, "status": status}


def test_a_watch_event_older_than_the_operators_own_write_is_dropped():
    """The status the operator wrote goes into the cache; the NetApp's earlier version, still on its way through
    the watch, must not put the old status back (its NetApp would be reconciled again)."""
    body = {"metadata": {"name": "det", "namespace": "robots", "generation": 1}, "spec": {"image": "x"}}
    cache = Cache()
    cache.on_netapp(_versioned(body, "12", url="http://a"), deleted=False)  # the operator's own status write
    cache.on_netapp(_versioned(body, "9"), deleted=False)  # the create's watch event, late
    assert cache.netapps[("robots", "det")]["status"] == {"url": "http://a"}
    cache.on_netapp(_versioned(body, "3", uid="u2"), deleted=False)  # deleted and made again: a new object
    assert cache.netapps[("robots", "det")]["status"] == {}
    cache.on_deployment(_versioned(deployment(), "7", readyReplicas=2), deleted=False)
    cache.on_deployment(_versioned(deployment(), "5"), deleted=False)
    assert cache.deployments[("robots", "det-edge")]["status"] == {"readyReplicas": 2}


def test_a_new_listing_replaces_the_children_and_says_what_changed():
    """After a watch ends the kube client lists again: what changed or went meanwhile queues its NetApp."""
    cache = Cache()
    same, changed, gone = (
        _versioned({**deployment(), "metadata": {**deployment()["metadata"], "name": n}}, "5") for n in "abc"
    )
    for dep in (same, changed, gone):
        cache.on_deployment(dep, deleted=False)
    new = _versioned({**deployment(), "metadata": {**deployment()["metadata"], "name": "d"}}, "8")
    reported = cache.relisted("Deployment", "robots", [same, _versioned(changed, "9"), new])
    assert sorted(r["metadata"]["name"] for r in reported) == ["b", "c", "d"]
    assert sorted(name for _, name in cache.deployments) == ["a", "b", "d"]


def test_a_new_netapp_listing_says_which_netapps_went_meanwhile():
    """The operator's NetApp watch lists again after it ends: the NetApps deleted meanwhile are forgotten."""
    cache = Cache()
    for namespace, name in (("robots", "a"), ("robots", "b"), ("other", "c")):
        cache.on_netapp({"metadata": {"namespace": namespace, "name": name}, "spec": {}}, deleted=False)
    listed = [{"metadata": {"namespace": "robots", "name": "a"}}]
    assert gone_netapps(cache, "robots", listed) == [("robots", "b")]
    assert sorted(gone_netapps(cache, None, listed)) == [("other", "c"), ("robots", "b")]


async def test_the_operators_netapp_watch_reports_listed_changed_gone_and_deleted_netapps():
    """watches.Watches.start_netapps (the NetApps' watch is the operator's, not kopf's): a listing reports the
    NetApps gone meanwhile, then each listed one; then each event, deleted or not."""

    def body(name: str) -> dict:
        return {"metadata": {"namespace": "robots", "name": name}, "spec": {}}

    class Kube:
        async def watch(self, kind, namespace, labels=None, timeout_s=0.0):
            assert (kind, namespace, labels) == ("NetApp", None, None)
            yield "LISTED", [body("a")]
            yield "MODIFIED", body("a")
            yield "DELETED", body("a")
            await asyncio.Event().wait()

    cache = Cache()
    cache.on_netapp(body("b"), deleted=False)
    seen: list[tuple[str, bool]] = []
    watches = Watches(Kube(), cache, lambda key: None, timeout_s=1.0)
    watches.start_netapps([None], lambda netapp, deleted: seen.append((netapp["metadata"]["name"], deleted)))
    for _ in range(100):
        if len(seen) == 4:
            break
        await asyncio.sleep(0.01)
    await watches.stop()
    assert seen == [("b", True), ("a", False), ("a", False), ("a", True)]
