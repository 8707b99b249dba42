"""The reconciler's planning over its cache (pure: no API calls)."""

from __future__ import annotations

import datetime

from netapp_operator import status
from netapp_operator.cache import Cache
from netapp_operator.config import OperatorConfig
from netapp_operator.reconcile import CHILD_REJECTED, FULL_CHECK_EVERY, Plan, Reconciler, may_leave_stale
from netapp_operator.spec import parse

from tests.operator.op_helpers import condition, node, nodepool

NOW = datetime.datetime(2026, 1, 1, 12, 0, tzinfo=datetime.timezone.utc)


def reconciler(*, edge_ready: bool = True) -> Reconciler:
    cache = Cache()
    cache.on_node(node("e1", {"p": "e"}, ready=edge_ready, address="10.0.0.5"), deleted=False)
    cache.on_node(node("c1", {"p": "c"}), deleted=False)
    cache.on_nodepool(nodepool("edge", "edge", {"p": "e"}, priority=5), deleted=False)
    cache.on_nodepool(nodepool("cloud", "cloud", {"p": "c"}), deleted=False)
    return Reconciler(kube=None, cache=cache, config=OperatorConfig(failover_grace_seconds=30))  # type: ignore


def netapp(status_: dict | None = None, generation: int = 1, **spec) -> dict:
    spec.setdefault("image", "img")
    return {
        "metadata": {"name": "det", "namespace": "ns", "uid": "u", "generation": generation},
        "spec": spec,
        "status": status_ or {},
    }


def plan_of(rec: Reconciler, na: dict, now: datetime.datetime) -> Plan:
    return rec.plan(na, parse(na["spec"]), now)


def needs_sync(rec: Reconciler, na: dict, now: datetime.datetime) -> bool:
    return rec.needs_sync(na, parse(na["spec"]), now)


def test_first_plan_places_and_a_placed_netapp_stays():
    rec = reconciler()
    plan = plan_of(rec, netapp(), NOW)
    assert (plan.action, plan.pool.name, plan.status["phase"]) == ("place", "edge", "Deploying")
    assert plan.status["url"] is None  # no Service (NodePort) yet
    again = plan_of(rec, netapp(plan.status), NOW)
    assert again.action == "stay" and condition({"status": again.status}, "Placed")["reason"] == "PoolSelected"


def test_needs_sync_is_false_when_nothing_changed():
    rec = reconciler()
    na = netapp(plan_of(rec, netapp(), NOW).status)
    rec.cache.on_deployment(
        {"metadata": {"name": "det-edge", "namespace": "ns"}, "spec": {"replicas": 1}}, deleted=False
    )
    assert needs_sync(rec, na, NOW)  # the Service is missing
    rec.cache.on_service(
        {"metadata": {"name": "det-edge", "namespace": "ns"}, "spec": {"ports": [{"name": "http", "nodePort": 30001}]}},
        deleted=False,
    )
    assert needs_sync(rec, na, NOW)  # now the URL is known: the status would change
    na = netapp(plan_of(rec, na, NOW).status)
    assert na["status"]["url"] == "http://10.0.0.5:30001"
    assert not needs_sync(rec, na, NOW)


def test_pool_loss_is_recorded_then_fails_over_after_the_grace_period():
    rec = reconciler()
    placed = plan_of(rec, netapp(), NOW).status
    down = reconciler(edge_ready=False)
    first = plan_of(down, netapp(placed), NOW)
    assert first.action == "stay"
    assert condition({"status": first.status}, status.POOL_AVAILABLE)["status"] == "False"
    later = plan_of(down, netapp(first.status), NOW + datetime.timedelta(seconds=31))
    assert (later.action, later.pool.name, later.reason) == ("move", "cloud", "FailedOver")


def test_a_spec_the_api_server_refused_is_not_retried_until_it_changes():
    rec = reconciler()
    refused = status.invalid_status({}, ["bad"], 3, NOW, CHILD_REJECTED)
    assert not needs_sync(rec, netapp(refused, generation=3), NOW)
    assert needs_sync(rec, netapp(refused, generation=4), NOW)


def test_only_a_changed_placement_or_spec_looks_for_stale_children():
    """Looking costs a list per child kind: a new or unchanged NetApp must not look (a burst of thousands)."""
    rec = reconciler()
    placed = plan_of(rec, netapp(), NOW).status
    assert not may_leave_stale(netapp(), placed)  # never reconciled: nothing of it can be elsewhere
    assert not may_leave_stale(netapp(placed), placed)  # synced again, unchanged
    assert may_leave_stale(netapp(placed), {**placed, "pool": "cloud"})  # moved
    assert may_leave_stale(netapp(placed, generation=2), placed)  # a new spec (an autoscaler dropped)
    warm = {**placed, "standby": {"pool": "cloud"}}
    assert may_leave_stale(netapp(warm), placed)  # the standby released
    assert not may_leave_stale(netapp(warm), warm)


async def test_the_periodic_pass_plans_every_netapp_only_when_the_pools_or_the_clock_may_change_a_plan():
    """A NetApp's own events and its children's queue it; the pass is for what they do not say (the pools, the
    grace period), and planning thousands of NetApps every few seconds for nothing is the idle operator's CPU."""
    rec = reconciler()
    rec.cache.on_netapp(netapp(), deleted=False)  # never reconciled: its plan differs from its status
    key = ("ns", "det")
    assert await rec.due(NOW) == [key]  # the first pass plans every NetApp
    assert await rec.due(NOW) == []  # nothing changed in the pools: no NetApp is planned
    rec.cache.on_node(node("e2", {"p": "e"}, address="10.0.0.6"), deleted=False)
    assert await rec.due(NOW) == [key]  # a node more
    rec.cache.on_node(node("e1", {"p": "e"}, ready=False, address="10.0.0.5"), deleted=False)
    rec.cache.on_node(node("e2", {"p": "e"}, ready=False, address="10.0.0.6"), deleted=False)
    assert await rec.due(NOW) == [key] and await rec.due(NOW) == [key]  # no ready node on edge: a grace may run
    rec.cache.on_node(node("e1", {"p": "e"}, address="10.0.0.5"), deleted=False)
    passes = [await rec.due(NOW) for _ in range(FULL_CHECK_EVERY)]
    assert passes[0] == [key] and passes[1:].count([]) == FULL_CHECK_EVERY - 2  # and one net in every so many
