"""Fixtures for the operator tests: a kmock-based API emulator and kopf running for real against it."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Any

import pytest

kopf = pytest.importorskip("kopf", reason="the operator extra is not installed (pip install '.[operator,test]')")
kmock = pytest.importorskip("kmock", reason="kmock is not installed (pip install '.[test]')")

from netapp_operator.config import OperatorConfig  # noqa: E402
from netapp_operator.kube import Kube, login_from_info  # noqa: E402

from tests.operator.op_harness import TEST_AGENT, Operator, running_operator  # noqa: E402
from tests.support.kube_emulator import Emulator, declare  # noqa: E402


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
        return await login_from_info(info)

    kube = Kube(login, manager=TEST_AGENT)
    yield kube
    await kube.close()


@pytest.fixture
def operator_config() -> OperatorConfig:
    # A short grace and check interval keep the failover test fast; the deadlines in tests stay generous.
    return OperatorConfig(failover_grace_seconds=1.0, check_interval_seconds=0.2)


@pytest.fixture
async def operator(emulator: Emulator, operator_config: OperatorConfig) -> AsyncIterator[Operator]:
    async with running_operator(emulator, operator_config) as op:
        yield op
