"""What one NetApp costs the API server, counted from the emulator's log: a fleet of thousands multiplies it."""

from __future__ import annotations

import gc
from typing import Any

import pytest
from netapp_operator.constants import (
    LABEL_INSTANCE,
    LABEL_MANAGED_BY,
    LABEL_NAME,
    NETAPP_APP_NAME,
    OPERATOR_MANAGER,
)
from netapp_operator.handlers import netapp_seen

from tests.operator.op_harness import TEST_AGENT, running_operator
from tests.operator.op_helpers import eventually, get_status, netapp, setup_pools

pytestmark = pytest.mark.timeout(120)

# 2 Secrets, 3 children, the status patch, the Placed Event: no patch of kopf's own (no create/update handlers).
NEW_NETAPP_REQUESTS = 7


def _name_of(request: Any) -> str:
    data = request.data if isinstance(request.data, dict) else {}
    return request.name or (data.get("metadata") or {}).get("name") or ""


def operator_requests(log: list[Any], prefix: str, agent: str | None = None) -> list[str]:
    """The operator's requests (not the test's) about objects named `prefix...`, as "ACTION plural/sub" lines."""
    out = []
    for request in log:
        user_agent = request.headers.get("User-Agent", "")
        if request.resource is None or user_agent == TEST_AGENT or (agent and not user_agent.startswith(agent)):
            continue
        if _name_of(request).startswith(prefix):
            sub = f"/{request.subresource}" if request.subresource else ""
            out.append(f"{request.action.value} {request.resource.plural}{sub}")
    return sorted(out)


async def _settled(api: Any, operator: Any, name: str) -> None:
    """Until the NetApp has its url and two periodic passes have run since."""

    async def handled() -> bool:
        na = await api.get("NetApp", "default", name)
        return bool((na.get("status") or {}).get("url"))

    await eventually(handled, what="status.url")
    checks = operator.runtime.checks
    await eventually(lambda: _true(operator.runtime.checks >= checks + 2), what="two periodic passes")


async def _true(value: bool) -> bool:
    return value


async def test_a_new_netapp_costs_seven_requests_and_no_list_nor_get(api, operator, emulator):
    """A list per NetApp is O(NetApps) on the server; a GET after its own status write doubles the work of a
    burst. Both happened once (bench/operator_bench.py: 3,000 NetApps never finished). Nor does kopf patch its
    bookkeeping onto the NetApp: the only write to it is the status."""
    await setup_pools(api)
    start = len(emulator.log)
    await api.apply(netapp("det"))
    await _settled(api, operator, "det")
    seen = operator_requests(emulator.log[start:], "det")
    assert not [r for r in seen if r.split()[0] in ("LIST", "FETCH")], seen
    assert [r for r in seen if r.endswith(" netapps")] == [], seen  # no annotation, no finalizer
    assert len(seen) <= NEW_NETAPP_REQUESTS, seen


async def test_what_start_up_made_is_out_of_the_cyclic_collector_while_the_operator_runs(operator):
    """handlers.startup freezes what start-up made (bench/operator_bench.py: the collector's full passes over it were
    a third of the operator's CPU in a burst); the clean-up gives it back."""
    assert gc.get_freeze_count() > 0


async def test_a_netapp_seen_again_costs_no_request(api, operator, emulator):
    """A NetApp's event (or a listing's item) queues it again, however often: a NetApp already placed with its
    children must then cost nothing, even with its old version from before the operator's own status write."""
    await setup_pools(api)
    first = await api.apply(netapp("det"))
    await _settled(api, operator, "det")
    body = await api.get("NetApp", "default", "det")
    start = len(emulator.log)
    for seen in (body, first):  # the latest, then a stale copy (its watch event still on the way)
        netapp_seen(operator.runtime, seen, deleted=False)
    checks = operator.runtime.checks
    await eventually(lambda: _true(operator.runtime.checks >= checks + 2), what="two periodic passes")
    assert operator_requests(emulator.log[start:], "det", agent=OPERATOR_MANAGER) == []
    assert (await get_status(api, "det"))["pool"] == "edge"


def _leftover(kind: str, api_version: str, name: str, instance: str, spec: dict[str, Any]) -> dict[str, Any]:
    labels = {LABEL_NAME: NETAPP_APP_NAME, LABEL_INSTANCE: instance, LABEL_MANAGED_BY: OPERATOR_MANAGER}
    return {
        "apiVersion": api_version,
        "kind": kind,
        "metadata": {"name": name, "namespace": "default", "labels": labels},
        "spec": spec,
    }


async def test_a_restarted_operator_lists_each_kind_once_and_removes_what_a_move_left(api, emulator, operator_config):
    """A restarted operator used to list five kinds per NetApp to find what a move stopped half-way had left: with
    thousands of NetApps, thousands of lists. Now one list per kind, and the leftovers still go."""
    names = ("a", "b", "c")
    await setup_pools(api)
    for name in names:
        await api.apply(netapp(name))
    async with running_operator(emulator, operator_config):
        for name in names:
            await eventually(lambda n=name: _url(api, n), what=f"{name}'s url")
    # What a move from cloud to edge left when the operator stopped between the new children and the old ones' removal.
    await api.apply(_leftover("Deployment", "apps/v1", "a-cloud", "a", {"replicas": 1}))
    await api.apply(_leftover("NetworkPolicy", "networking.k8s.io/v1", "a-cloud", "a", {"podSelector": {}}))
    start = len(emulator.log)
    async with running_operator(emulator, operator_config) as second:

        async def removed() -> bool:
            return all([await api.get(kind, "default", "a-cloud") is None for kind in ("Deployment", "NetworkPolicy")])

        await eventually(removed, what="the leftovers of the move to go")
        await _settled(api, second, "c")
    lists = [r for r in emulator.log[start:] if r.action is not None and r.action.value == "list" and _ours(r)]
    selectors = [r.params.get("labelSelector", "") for r in lists]
    assert not [s for s in selectors if LABEL_INSTANCE in s], selectors  # none per NetApp
    assert len(lists) <= 7, [r.resource.plural for r in lists]  # Nodes, NodePools, five child kinds
    for name in names:  # and every NetApp kept its children
        assert await api.get("Deployment", "default", f"{name}-edge") is not None


def _ours(request: Any) -> bool:
    return request.headers.get("User-Agent", "").startswith(OPERATOR_MANAGER)


async def _url(api: Any, name: str) -> str | None:
    return (await get_status(api, name)).get("url")
