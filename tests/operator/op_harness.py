"""Run the operator (kopf, the real handlers) in the test's event loop against the API emulator."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
from collections.abc import AsyncIterator
from typing import Any

import kopf
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
