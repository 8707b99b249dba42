"""Run the operator (kopf, the real handlers) in the test's event loop against the API emulator."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import pathlib
from collections.abc import AsyncIterator
from typing import Any

import kopf
import yaml
from netapp_operator.config import OperatorConfig
from netapp_operator.handlers import Runtime, register

from tests.operator.op_helpers import eventually
from tests.support.kube_emulator import Emulator

TEST_AGENT = "netapp-operator-tests"  # the User-Agent of the tests' own API client


@dataclasses.dataclass
class Operator:
    runtime: Runtime
    task: asyncio.Task[Any]

    @property
    def alive(self) -> bool:
        return not self.task.done()


@contextlib.asynccontextmanager
async def running_operator(emulator: Emulator, config: OperatorConfig) -> AsyncIterator[Operator]:
    """kopf running the real handlers in this event loop, cluster-wide (kmock cannot list namespaces)."""
    registry = kopf.OperatorRegistry()
    info = kopf.ConnectionInfo(server=str(emulator.url).rstrip("/"))
    runtime = register(registry, config, connection=info)
    settings = kopf.OperatorSettings()
    ready, stop = asyncio.Event(), asyncio.Event()
    # spawn_tasks + our own wait instead of kopf.operator(): kopf.operator() treats every task created after its
    # start as its own and cancels it at exit (with a 5 s wait), and in a test that includes pytest's tasks.
    tasks = await kopf.spawn_tasks(
        registry=registry, settings=settings, clusterwide=True, standalone=True, ready_flag=ready, stop_flag=stop
    )
    task = asyncio.create_task(_run(tasks))
    await asyncio.wait_for(ready.wait(), timeout=30)

    async def checked() -> bool:
        return runtime.checks >= 1  # the watches have started and one periodic pass ran

    await eventually(checked, timeout=30, what="the operator's first periodic check")
    try:
        yield Operator(runtime, task)
    finally:
        stop.set()
        await asyncio.wait_for(task, timeout=30)


async def _run(tasks: list[asyncio.Task[Any]]) -> None:
    """Run kopf's root tasks until one ends (the stop flag ends them), then stop the rest."""
    _, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    for t in pending:
        t.cancel()
    if pending:
        await asyncio.wait(pending, timeout=20)


VERBS = {"list": "list", "watch": "watch", "fetch": "get", "create": "create", "update": "patch", "delete": "delete"}
MANIFESTS = pathlib.Path(__file__).resolve().parents[2] / "manifests" / "netapp-toolkit.yaml"


def denied_requests(emulator: Emulator) -> tuple[list[tuple[str, str, str]], dict[str, Any]]:
    """The (group, resource, verb) of the operator's requests so far that the ClusterRole `kubectl apply -f
    manifests/` grants (rendered from the chart, all namespaces) does not allow, and that role."""
    [role] = [
        d
        for d in yaml.safe_load_all(MANIFESTS.read_text())
        if d and d["kind"] == "ClusterRole" and d["metadata"]["name"].endswith("-operator")
    ]
    used = set()
    for request in emulator.log:
        if (
            request.resource is None
            or not request.resource.plural
            or request.action is None
            or request.headers.get("User-Agent") == TEST_AGENT
        ):  # discovery needs no RBAC rule
            continue
        resource = request.resource.plural + (f"/{request.subresource}" if request.subresource else "")
        used.add((request.resource.group, resource, VERBS[request.action.value.lower()]))
    assert used, "no operator request was recorded"
    rules = role["rules"]
    allowed = [
        u for u in used if any(u[0] in r["apiGroups"] and u[1] in r["resources"] and u[2] in r["verbs"] for r in rules)
    ]
    return sorted(set(used) - set(allowed)), role
