"""A NetApp's new model tried by the operator on its running netapp, end to end: kopf against the API emulator, a
real netapp (uvicorn on loopback, onnxruntime, YOLOX-Nano) standing in for the NetApp's one pod, robots streaming.
A re-export agrees and is promoted (the Deployment renders it, an Event says so); a model whose answers are garbage
is rolled back (the Deployment keeps the served model, a Warning Event says why). The robots see no error."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import http.server
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
from netapp_operator import render
from netapp_operator.config import OperatorConfig
from netapp_operator.rollout_status import CONDITION

from netapp.models import Detector, DetectorConfig
from netapp.server.access import token_digest
from netapp.server.settings import Settings
from tests.operator.op_harness import running_operator
from tests.operator.op_helpers import condition, eventually, get_status, netapp, setup_pools
from tests.operator.test_operator_kopf import events_for
from tests.support.rollout_robots import UNJUDGED_SPEED, Fleet, reexport

TOKEN = "operator-rollout-token"
QUICK = {"promoteAfter": 20, "shadowSample": 0.5, "shadowBudget": 5, "maxSlowdown": UNJUDGED_SPEED}  # a test's pace


@contextlib.contextmanager
def model_server(directory: Path) -> Iterator[str]:
    """The models over HTTP on loopback, as a NetApp's model.url names them."""
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(directory))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


async def one_pod_ready(api: Any, name: str = "det-edge-0") -> None:
    """What the kubelet and the Deployment controller would report: the pod Ready, the Deployment available."""
    await api.create(ready_pod(name, render.labels("det", "edge")))
    available = {"replicas": 1, "readyReplicas": 1, "availableReplicas": 1}
    await api.patch_status("Deployment", "default", "det-edge", available)
    await eventually(lambda: _ready(api), what="the NetApp Ready")


async def _ready(api: Any) -> bool:
    return (await get_status(api, "det")).get("readyReplicas") == 1


def ready_pod(name: str, labels: dict[str, str]) -> dict[str, Any]:
    """The NetApp's pod as a kubelet would report it: Running, Ready, at the loopback netapp's address."""
    return {
        "apiVersion": "v1",
        "kind": "Pod",
        "metadata": {"name": name, "namespace": "default", "labels": labels},
        "status": {"phase": "Running", "podIP": "127.0.0.1", "conditions": [{"type": "Ready", "status": "True"}]},
    }


async def verdict(api: Any, candidate: str) -> dict[str, Any]:
    """The NetApp's status once the rollout of `candidate` has its verdict, else {}."""
    status = await get_status(api, "det")
    rollout = status.get("rollout") or {}
    return (
        status if rollout.get("candidate") == candidate and rollout.get("phase") in ("Promoted", "RolledBack") else {}
    )


async def deployed_model(api: Any) -> str:
    dep = await api.get("Deployment", "default", "det-edge")
    [fetch] = dep["spec"]["template"]["spec"]["initContainers"]
    return {e["name"]: e["value"] for e in fetch["env"]}["MODEL_URL"]


async def test_a_new_model_is_shadowed_then_promoted_and_a_garbage_one_rolled_back(
    emulator, api, serve, real_model_path, tiny_model_path, media_dir, tmp_path
):
    models = tmp_path / "models"
    models.mkdir()
    (models / "yolox_nano.onnx").write_bytes(real_model_path.read_bytes())
    reexport(real_model_path, models / "yolox_nano_v2.onnx")
    (models / "garbage.onnx").write_bytes(tiny_model_path.read_bytes())  # always one `robot` in a corner
    settings = Settings(lanes=1, admin_token_sha256=token_digest(TOKEN))  # what the Deployment's env gives it
    server = serve(Detector(DetectorConfig(str(real_model_path))), settings)
    port = int(server.url.rsplit(":", 1)[1])
    image = cv2.imread(str(media_dir / "ped100.jpg"))
    config = OperatorConfig(check_interval_seconds=0.2, rollout_token=TOKEN, rollout_poll_seconds=0.2)
    with model_server(models) as base:
        async with running_operator(emulator, config) as operator:
            await setup_pools(api)
            await api.apply(netapp("det", port=port, model={"url": f"{base}/yolox_nano.onnx"}, rollout=QUICK))
            placed = await eventually(lambda: get_status(api, "det"), what="the NetApp placed")
            await eventually(lambda: _has_model(api), what="status.model recorded")
            assert placed["pool"] == "edge"
            await one_pod_ready(api)

            # A re-export agrees: promoted, and the Deployment renders it (its pods roll to it).
            fleet = Fleet(server.url, image)
            await api.apply(netapp("det", port=port, model={"url": f"{base}/yolox_nano_v2.onnx"}, rollout=QUICK))
            status = await eventually(lambda: verdict(api, f"{base}/yolox_nano_v2.onnx"), timeout=90)
            await asyncio.to_thread(fleet.finish)
            rollout = status["rollout"]
            assert rollout["phase"] == "Promoted", rollout
            assert float(rollout["agreement"]) >= 0.95 and rollout["framesCompared"] >= 20 and rollout["errors"] == 0
            assert rollout["pod"] == "det-edge-0" and rollout["candidate"] == f"{base}/yolox_nano_v2.onnx"
            assert status["model"] == {"url": f"{base}/yolox_nano_v2.onnx"}
            promoted_condition = await eventually(lambda: _rollout_condition(api, "True"), what="ModelRollout True")
            assert promoted_condition["reason"] == "Promoted"
            await eventually(lambda: _deployed_is(api, f"{base}/yolox_nano_v2.onnx"), what="the Deployment rendered")
            [promoted] = [e for e in await events_for(api, "det") if e["reason"] == "RolloutPromoted"]
            assert promoted["type"] == "Normal" and "yolox_nano_v2.onnx promoted after" in promoted["message"]

            # A model whose answers are garbage: rolled back, the Deployment keeps the served model.
            fleet = Fleet(server.url, image)
            await api.apply(netapp("det", port=port, model={"url": f"{base}/garbage.onnx"}, rollout=QUICK))
            status = await eventually(lambda: verdict(api, f"{base}/garbage.onnx"), timeout=90)
            await asyncio.to_thread(fleet.finish)
            rollout = status["rollout"]
            assert rollout["phase"] == "RolledBack" and "agreement (F1)" in rollout["reason"], rollout
            assert status["model"] == {"url": f"{base}/yolox_nano_v2.onnx"}  # what is served; not spec.model
            rolled = await eventually(lambda: _rollout_condition(api, "False"), what="ModelRollout False")
            assert f"the pods serve {base}/yolox_nano_v2.onnx" in rolled["message"]
            assert await deployed_model(api) == f"{base}/yolox_nano_v2.onnx"
            [warning] = [e for e in await events_for(api, "det") if e["reason"] == "RolloutRolledBack"]
            assert warning["type"] == "Warning" and "garbage.onnx rolled back: " in warning["message"]
            assert "\n" not in warning["message"]
            assert operator.alive


async def _rollout_condition(api: Any, value: str) -> dict[str, Any]:
    found = condition({"status": await get_status(api, "det")}, CONDITION)
    return found if found.get("status") == value else {}


async def _has_model(api: Any) -> bool:
    return "model" in await get_status(api, "det")


async def _deployed_is(api: Any, url: str) -> bool:
    return await deployed_model(api) == url


async def test_a_netapp_that_does_not_answer_is_shown_and_retried_and_the_pods_keep_their_model(emulator, api):
    config = OperatorConfig(check_interval_seconds=0.2, rollout_token=TOKEN, rollout_poll_seconds=0.2)
    with socket.socket() as closed:  # a port nobody listens on: bound, never listening
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
        async with running_operator(emulator, config) as operator:
            await setup_pools(api)
            await api.apply(netapp("det", port=port, model={"url": "https://m/v1.onnx"}))
            await eventually(lambda: _has_model(api), what="status.model recorded")
            await one_pod_ready(api)
            await api.apply(netapp("det", port=port, model={"url": "https://m/v2.onnx"}))
            shown = await eventually(lambda: _rollout_says(api, "cannot reach pod det-edge-0 at http://127.0.0.1"))
            assert shown["rollout"]["phase"] == "Pending" and shown["model"] == {"url": "https://m/v1.onnx"}
            await eventually(lambda: _rollout_condition(api, "Unknown"), what="ModelRollout Unknown")
            assert await deployed_model(api) == "https://m/v1.onnx"
            assert operator.alive


async def _rollout_says(api: Any, words: str) -> dict[str, Any]:
    status = await get_status(api, "det")
    return status if words in str((status.get("rollout") or {}).get("reason")) else {}


async def test_a_netapp_with_no_ready_replica_takes_a_new_model_at_once(emulator, api):
    """Nothing serves that a candidate could be compared with (e.g. the old model's URL was wrong): no rollout."""
    config = OperatorConfig(check_interval_seconds=0.2, rollout_token=TOKEN, rollout_poll_seconds=0.2)
    async with running_operator(emulator, config):
        await setup_pools(api)
        await api.apply(netapp("det", model={"url": "https://m/typo.onnx"}))
        await eventually(lambda: _has_model(api), what="status.model recorded")
        await api.apply(netapp("det", model={"url": "https://m/v1.onnx"}))
        await eventually(lambda: _deployed_is(api, "https://m/v1.onnx"), what="the Deployment rendered")
        status = await get_status(api, "det")
        assert status["model"] == {"url": "https://m/v1.onnx"} and "rollout" not in status
