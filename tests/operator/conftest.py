"""Fixtures for the operator tests: a kmock-based API emulator and kopf running for real against it."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
from collections.abc import AsyncIterator
from typing import Any

import pytest

kopf = pytest.importorskip("kopf", reason="the operator extra is not installed (pip install '.[operator,test]')")
kmock = pytest.importorskip("kmock", reason="kmock is not installed (pip install '.[test]')")

from netapp_operator.config import OperatorConfig  # noqa: E402
from netapp_operator.handlers import Runtime, register  # noqa: E402
from netapp_operator.kube import Kube  # noqa: E402
from netapp_operator.testing import Emulator, declare  # noqa: E402

from op_helpers import eventually  # noqa: E402


TEST_AGENT = "netapp-operator-tests"


@pytest.fixture
async def emulator() -> AsyncIterator[Emulator]:
    async with Emulator() as em, kmock.Server(em):
        declare(em)
        yield em


@pytest.fixture
async def api(emulator: Emulator) -> AsyncIterator[Kube]:
    """The operator's own thin client, pointed at the emulator (what a user's kubectl would do)."""
    info = kopf.ConnectionInfo(server=str(emulator.url).rstrip("/"))

    async def login() -> Any:
        return info

    kube = Kube(login, user_agent=TEST_AGENT)
    yield kube
    await kube.close()


@dataclasses.dataclass
class Operator:
    runtime: Runtime
    task: asyncio.Task[Any]

    @property
    def alive(self) -> bool:
        return not self.task.done()


@pytest.fixture
def operator_config() -> OperatorConfig:
    # A short grace and check interval keep the failover test fast; the deadlines in tests stay generous.
    return OperatorConfig(failover_grace_seconds=1.0, check_interval_seconds=0.2)


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
        registry=registry, settings=settings, clusterwide=True, standalone=True,
        ready_flag=ready, stop_flag=stop)
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


@pytest.fixture
async def operator(emulator: Emulator, operator_config: OperatorConfig) -> AsyncIterator[Operator]:
    async with running_operator(emulator, operator_config) as op:
        yield op


async def _run(tasks: list[asyncio.Task[Any]]) -> None:
    """Run kopf's root tasks until one ends (the stop flag ends them), then stop the rest."""
    _, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    for t in pending:
        t.cancel()
    if pending:
        await asyncio.wait(pending, timeout=20)
