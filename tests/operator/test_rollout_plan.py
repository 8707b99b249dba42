"""One rollout planner for both backends (netapp_operator.rollout_plan): its rules, the operator's reading of a
NetApp's status into them, and the middleware's driver doing what it says with nothing but its I/O."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from netapp_middleware.backends.base import READY, InstanceState, RolloutRefused
from netapp_middleware.catalogue import parse_catalogue
from netapp_middleware.deployments import Registry
from netapp_middleware.model_rollouts import ModelRollouts
from netapp_operator import rollouts
from netapp_operator.rollout_plan import (
    FOLLOW,
    LEAVE,
    PENDING,
    PROMOTED,
    REFUSED,
    ROLLED_BACK,
    RUNNING,
    START,
    Attempt,
    announce_now,
    next_step,
    stage_of,
)

from tests.middleware.mw_helpers import NullBackend

V1, V2, V3 = "v1", "v2", "v3"


@pytest.mark.parametrize(
    "wanted, serving, ready, last, request_, step",
    [
        (V2, V1, True, None, None, START),  # a new model on a ready netapp
        (V1, V1, True, None, None, LEAVE),  # it serves what it wants
        (None, V1, True, None, None, LEAVE),  # nothing to try (a volume's model, a processor with its own weights)
        (V2, None, True, None, None, LEAVE),  # what it serves is unknown: nothing to compare the new one with
        (V2, V1, False, None, None, LEAVE),  # not ready
        (V2, V1, True, Attempt(V2, RUNNING, on="pod-0"), None, FOLLOW),
        (V3, V1, True, Attempt(V2, RUNNING, on="pod-0"), None, FOLLOW),  # followed to its verdict, whatever is wanted
        (V1, V1, False, Attempt(V2, RUNNING, on="pod-0"), None, FOLLOW),
        (V2, V1, True, Attempt(V2, PENDING), None, START),  # no pod yet, or its netapp did not answer: again
        (V2, V1, True, Attempt(V2, ROLLED_BACK, on="pod-0"), None, LEAVE),  # tried once, whatever its verdict
        (V2, V1, True, Attempt(V2, PROMOTED, on="pod-0"), None, LEAVE),
        (V3, V1, True, Attempt(V2, ROLLED_BACK, on="pod-0"), None, START),  # another model: tried
        (V2, V1, True, Attempt(V2, REFUSED, request={"a": 1}), {"a": 1}, LEAVE),  # refused as it stands
        (V2, V1, True, Attempt(V2, REFUSED, request={"a": 1}), {"a": 2}, START),  # the request changed
    ],
)
def test_the_planner_starts_follows_or_leaves(wanted, serving, ready, last, request_, step) -> None:
    assert next_step(wanted, serving, ready, last, request_) == step


def test_a_verdict_is_announced_once_and_both_vocabularies_read_the_same() -> None:
    assert announce_now(RUNNING, ROLLED_BACK) and announce_now(None, REFUSED) and announce_now(PENDING, PROMOTED)
    assert not announce_now(PROMOTED, PROMOTED) and not announce_now(RUNNING, RUNNING)
    for netapps, statuses, stage in [
        ("shadow", "Shadow", RUNNING),
        ("canary", "Canary", RUNNING),
        ("promoted", "Promoted", PROMOTED),
        ("rolled_back", "RolledBack", ROLLED_BACK),
        (None, "Pending", PENDING),
    ]:
        assert stage_of(netapps) == stage_of(statuses) == stage


def test_the_operator_reads_a_netapps_status_into_the_planner() -> None:
    v1, v2, v3 = ({"url": f"https://m/{v}.onnx"} for v in (V1, V2, V3))

    def netapp(**status: Any) -> dict[str, Any]:
        return {"spec": {}, "status": {"pool": "edge", "readyReplicas": 1, "model": v1, **status}}

    running = {"phase": "Shadow", "target": v2, "pod": "det-edge-0"}
    assert rollouts.next_step(netapp(), v2, None) == START
    assert rollouts.next_step(netapp(), v2, running) == FOLLOW
    assert rollouts.next_step(netapp(), v3, running) == FOLLOW  # the one under way first
    assert rollouts.next_step(netapp(), v2, {**running, "phase": "RolledBack"}) == LEAVE
    assert rollouts.next_step(netapp(), v3, {**running, "phase": "RolledBack"}) == START
    assert rollouts.next_step(netapp(readyReplicas=0), v2, None) == LEAVE
    assert rollouts.next_step(netapp(), {"volume": {"claimName": "c", "path": "p"}}, None) == LEAVE
    assert rollouts.active(netapp(rollout=running), v3)


class RolloutBackend(NullBackend):
    """A backend whose netapp answers rollouts as the test says; it records every call."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, Any]] = []
        self.answers: list[Any] = []  # what the next calls answer (an exception is raised)
        self.announced: list[str] = []

    async def rollout(self, name: str, spec: dict[str, Any]) -> dict[str, Any]:
        return self._answer("rollout", spec["rollout"]["candidate"])

    async def rollout_state(self, name: str) -> dict[str, Any] | None:
        return self._answer("state", name)

    async def announce(self, name, type_, reason, message) -> None:
        self.announced.append(reason)

    def _answer(self, call: str, what: Any) -> Any:
        self.calls.append((call, what))
        answer = self.answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        return answer


async def test_the_middleware_driver_does_what_the_planner_says_with_only_its_io() -> None:
    backend = RolloutBackend()
    registry = Registry(backend)
    entry: dict[str, Any] = {"image": "x", "model": {"url": "v1.onnx"}}
    catalogue = {"detect": {"spec": entry}}
    rollouts_ = ModelRollouts(registry, lambda: parse_catalogue(catalogue))
    instance = registry.create("r", parse_catalogue(catalogue).get("detect"), None, True).instance
    registry.report(instance.name, InstanceState(READY, "http://n:1"))

    async def tick(*answers: Any) -> list[tuple[str, Any]]:
        backend.calls, backend.answers = [], list(answers)
        await rollouts_.tick()
        assert backend.answers == [], "an answer was not asked for"
        return backend.calls

    assert await tick() == []  # it serves what the catalogue names
    entry["rollout"] = {"candidate": "v2.onnx", "maxSlowdown": 0.5}
    assert await tick(ValueError("the netapp is stopping")) == [("rollout", "v2.onnx")]  # not there: no refusal,
    assert await tick(RolloutRefused("max_slowdown must be 1 or more")) == [("rollout", "v2.onnx")]  # asked again
    assert await tick() == []  # refused as it stands: said once, not asked again
    entry["rollout"] = {"candidate": "v2.onnx"}
    shadow = {"phase": "shadow", "model": "v2.onnx"}
    assert await tick(shadow) == [("rollout", "v2.onnx")]  # the request changed: tried again
    entry["rollout"] = {"candidate": "v3.onnx"}  # changed under way: the one running is followed to its verdict
    assert await tick(shadow) == [("state", instance.name)]
    assert await tick({"phase": "rolled_back", "model": "v2.onnx", "serving": "v1"}) == [("state", instance.name)]
    assert instance.model_key == ("v1.onnx", "")  # rolled back: it serves what it had
    assert await tick({"phase": "shadow", "model": "v3.onnx"}) == [("rollout", "v3.onnx")]
    assert await tick({"phase": "promoted", "model": "v3.onnx", "serving": "v3"}) == [("state", instance.name)]
    assert instance.model_key == ("v3.onnx", "")  # promoted: it serves the new one
    assert await tick() == []
    assert backend.announced == ["RolloutRefused", "RolloutRolledBack", "RolloutPromoted"]  # each verdict once
    assert [s["phase"] for s in rollouts_.of_app("detect")] == ["promoted"]
    await asyncio.sleep(0)
