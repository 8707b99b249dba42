"""A NetApp means one thing on both backends: the local backend runs the command the operator's container runs
(netapp_operator.serve_command), less only what a cluster has (render.CLUSTER_ONLY_ARGS / CLUSTER_ONLY_ENV), and
refuses, by name, what one machine cannot honour; the robot hears that refusal at once, as a 4xx."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import pytest
import requests
from netapp_middleware.backends.local import LocalBackend, netapp_command, netapp_env
from netapp_middleware.catalogue import DEFAULT_CATALOGUE, parse_catalogue, render_spec
from netapp_operator import render
from netapp_operator.config import OperatorConfig
from netapp_operator.placement import Pool
from netapp_operator.serve_command import one_machine_refusal
from netapp_operator.spec import parse

from netapp.client.middleware import MiddlewareClient, MiddlewareError
from tests.middleware.mw_helpers import ROBOTS

MODEL_URL = "https://models.example.org/yolox_nano.onnx"
SPEC: dict[str, Any] = {
    "image": "ghcr.io/netapp-toolkit/netapp:0.1.0-tracking",
    "processor": "object-tracking",
    "model": {"url": MODEL_URL, "sha256": "a" * 64, "timeoutSeconds": 120},
    "device": "cpu",
    "admission": "measured",
    "priority": {"robots": "low", "tokenSha256": {"high": "b" * 64}, "weights": {"high": 8}},
    "state": {"volume": {"claimName": "tracks"}},
    "sources": [{"name": "door", "url": "rtsp://10.0.0.5/stream"}],
    "webrtc": {"iceServers": ["stun:stun.example.org:3478"]},
    "publish": [{"url": "mqtt://mosquitto.messaging/"}],
    "rtp": {"firstPort": 31000, "count": 2},
    "args": ["--conf", "0.4"],
    "env": [{"name": "LOG_LEVEL", "value": "debug"}],
}
# The values each runtime chooses for itself (where it listens and keeps its files); the flags are the spec's.
WHERE_FLAGS = ("--host", "--port", "--model", "--state-dir", "--trt-cache")
# How the netapp fetches its model itself; in a cluster an init container does it (render._model)
FETCH_FLAGS = ("--sha256", "--download-timeout")


def without(args: list[str], flags: tuple[str, ...]) -> list[str]:
    """`args` less each of `flags` and the value after it."""
    out, skip = [], False
    for arg in args:
        if not skip and arg in flags:
            skip = True
        elif skip:
            skip = False
        else:
            out.append(arg)
    return out


def placeholders(args: list[str]) -> list[str]:
    """`args` with the runtime's own values (WHERE_FLAGS') as a placeholder."""
    return ["<here>" if i and args[i - 1] in WHERE_FLAGS else a for i, a in enumerate(args)]


def container(spec: dict[str, Any]) -> dict[str, Any]:
    netapp = {"metadata": {"name": "track", "namespace": "robots", "uid": "u-1"}, "spec": spec}
    pool = Pool("edge", "edge", False, 0, {"nodeSelector": {"pool": "edge"}}, 1, 1, ("192.168.1.10",))
    config = OperatorConfig(rollout_token="t")  # the operator's rollout token: its digest is a cluster's env
    deployment = render.render_deployment(netapp, parse(spec), pool, config)
    [made] = deployment["spec"]["template"]["spec"]["containers"]
    return made


def test_the_local_backend_runs_the_operators_command_less_what_only_a_cluster_has(tmp_path: Path) -> None:
    assert parse(SPEC).problems == () and one_machine_refusal(parse(SPEC), gpu=False) is None
    pod = container(SPEC)
    local = netapp_command(SPEC, 9000, base=["netapp", "serve"], work_dir=tmp_path)
    assert local[:2] == ["netapp", "serve"]
    cluster_only = [a for a in pod["args"] if a in render.CLUSTER_ONLY_ARGS]
    assert cluster_only == ["--drain-grace", "--camera-leases"]  # the pod's drain; its cameras' Leases
    shared = placeholders(without(pod["args"], render.CLUSTER_ONLY_ARGS))
    assert placeholders(without(local[2:], FETCH_FLAGS)) == shared
    for flag, value in [
        ("--processor", "object-tracking"),
        ("--device", "cpu"),
        ("--admission", "measured"),
        ("--robot-priority", "low"),
        ("--priority-token", "high=" + "b" * 64),
        ("--priority-weights", "high=8"),
        ("--source", "door=rtsp://10.0.0.5/stream"),
        ("--rtp-ports", "31000-31001"),
        ("--ice-server", "stun:stun.example.org:3478"),
    ]:
        assert local[local.index(flag) + 1] == pod["args"][pod["args"].index(flag) + 1] == value, flag
    assert local[-2:] == pod["args"][-2:] == ["--conf", "0.4"]  # the spec's own args last: they win
    # each runtime's places: the pod's mounts; here the netapp fetches its model and writes a directory of the claim
    assert pod["args"][pod["args"].index("--model") + 1] == "/models/model.onnx"
    assert local[local.index("--model") :][:6] == [
        "--model",
        MODEL_URL,
        "--sha256",
        "a" * 64,
        "--download-timeout",
        "120",
    ]
    assert pod["args"][pod["args"].index("--state-dir") + 1] == "/var/lib/netapp/state"
    assert local[local.index("--state-dir") + 1] == str(tmp_path / "claims" / "tracks")
    # the environment: the spec's on both, and around it in the pod only what a cluster has
    names = [e["name"] for e in pod["env"]]
    assert [n for n in names if n not in render.CLUSTER_ONLY_ENV] == ["LOG_LEVEL"]
    assert netapp_env(SPEC, "track-1", "tracking")["LOG_LEVEL"] == "debug"


def test_the_pods_tls_and_token_are_a_clusters_and_the_local_backend_refuses_them() -> None:
    spec = {**SPEC, "tls": {"secretName": "cert"}, "access": {"requireToken": True}}
    pod = container(spec)
    assert [a for a in pod["args"] if a in render.CLUSTER_ONLY_ARGS] == [
        "--drain-grace",
        "--camera-leases",
        "--tls-cert",
        "--tls-key",
    ]
    assert [e["name"] for e in pod["env"] if e["name"] not in render.CLUSTER_ONLY_ENV] == ["LOG_LEVEL"]
    assert one_machine_refusal(parse(spec), gpu=True).startswith("spec.tls.secretName")


@pytest.mark.parametrize(
    "field, says",
    [
        ({"replicas": 2}, "spec.replicas: 2: one machine runs one netapp process"),
        ({"replicas": 0}, "spec.replicas: 0"),
        ({"autoscaling": {"maxReplicas": 3}}, "spec.autoscaling"),
        ({"standby": {"policy": "nextBest"}}, "spec.standby"),
        ({"model": {"volume": {"claimName": "models", "path": "m.onnx"}}}, "spec.model.volume"),
        ({"tls": {"secretName": "cert"}}, "spec.tls.secretName"),
        ({"access": {"requireToken": True}}, "spec.access.requireToken"),
        ({"webrtc": {"iceServers": ["turn:t.example.org:3478"], "turnSecret": "turn"}}, "spec.webrtc.turnSecret"),
        ({"publish": [{"url": "amqp://netapp@rabbit/", "secret": "rabbit"}]}, "spec.publish.secret"),
        ({"placement": {"requireGPU": True}}, "spec.placement.requireGPU needs a GPU"),
        ({"resources": {"gpus": 1}}, "spec.resources.gpus needs a GPU"),
        ({"device": "cuda"}, "spec.device: cuda needs a GPU"),
        ({"device": "tpu"}, "spec.device must be one of"),  # the spec's own problems first, as the operator's
    ],
)
def test_a_field_one_machine_cannot_honour_is_refused_by_name(field: dict[str, Any], says: str) -> None:
    spec = {"image": "x", **field}
    backend = LocalBackend(gpu=False)
    refused = backend.refuse(spec)
    assert refused is not None and refused.startswith(says) and "\n" not in refused, refused
    with pytest.raises(ValueError, match=says.split(":")[0]):
        asyncio.run(backend.create("x-1", "x", None, spec, {}))
    assert backend.pids() == {}  # nothing started
    asyncio.run(backend.close())
    gpu_field = any(k in field for k in ("placement", "resources")) or field.get("device") == "cuda"
    assert (one_machine_refusal(parse(spec), gpu=True) is None) == gpu_field  # with a GPU, those are honoured


def test_the_built_in_apps_run_on_one_machine_and_a_containers_fields_are_not_the_netapps() -> None:
    for app in parse_catalogue(DEFAULT_CATALOGUE).apps.values():
        for placement in (None, "edge", "cloud", "my-pool"):
            assert LocalBackend(gpu=False).refuse(render_spec(app, placement)) is None, app.name
    # image, port and resources are a container's: one machine runs its own netapp on a free port, unlimited
    assert one_machine_refusal(parse({"port": 0, "resources": {"cpu": "lots"}}), gpu=False) is None


def test_the_robot_hears_a_refusal_at_once_as_a_4xx_on_both_apis(start_middleware: Any, tmp_path: Path) -> None:
    catalogue = {
        "fleet": {"spec": {"image": "x", "replicas": 3}, "taskId": "3b2ea0d6-3c1e-4d0f-8d7b-1e2f3a4b5c6d"},
        "gpu": {"spec": {"image": "x", "device": "tensorrt"}},
    }
    backend = LocalBackend(gpu=False)
    server = start_middleware(backend, catalogue)
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        for app, says in (("fleet", "spec.replicas: 3"), ("gpu", "spec.device: tensorrt needs a GPU")):
            started = time.monotonic()
            with pytest.raises(MiddlewareError, match=says) as refused:
                mw.deploy(app, timeout=60)
            assert refused.value.status == 422 and time.monotonic() - started < 10  # at once, not at a timeout
    assert server.services.registry.list("robot-1") == []
    login = requests.post(f"{server.url}/Login", json={"Id": "robot-1", "Password": ROBOTS["robot-1"]}, timeout=10)
    plan = requests.post(
        f"{server.url}/Task/Plan",
        json={"TaskId": catalogue["fleet"]["taskId"], "RobotId": "3f7f5d8e-6a0b-4c39-9a55-2f0f3c6f3b11"},
        headers={"Authorization": f"Bearer {login.json()['token']}"},
        timeout=10,
    )
    assert plan.status_code == 422 and "spec.replicas: 3" in plan.json()["message"]
    assert backend.pids() == {} and server.services.registry.instances() == []


def test_a_catalogue_app_runs_locally_with_its_processor_device_admission_and_state(
    start_middleware: Any, tiny_model_path: Path, jpeg: bytes
) -> None:
    """The issue's example, on a real netapp process: `processor`, `device` and `admission` reach it (they were
    ignored once), and its `--state-dir` is the directory of the spec's state claim."""
    import queue

    import psutil

    from tests.middleware.mw_helpers import DEADLINE_S, send_until_result

    spec = {
        "image": "x",
        "processor": "object-tracking",
        "device": "cpu",
        "admission": "measured",
        "priority": {"robots": "high"},
        "state": {"volume": {"claimName": "tracks"}},
    }
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S, gpu=False)
    server = start_middleware(backend, {"tracking": {"spec": spec}})
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("tracking", timeout=2 * DEADLINE_S)
        (pid,) = backend.pids().values()
        argv = psutil.Process(pid).cmdline()
        for flag, value in [
            ("--processor", "object-tracking"),
            ("--device", "cpu"),
            ("--admission", "measured"),
            ("--robot-priority", "high"),
        ]:
            assert argv[argv.index(flag) + 1] == value, argv
        state_dir = Path(argv[argv.index("--state-dir") + 1])
        assert state_dir.name == "tracks" and state_dir.is_dir()
        results: queue.Queue[Any] = queue.Queue()
        with mw.netapp_client(endpoint, transport="ws", on_result=results.put) as client:
            assert send_until_result(lambda: client.send(jpeg), results).detections  # it serves, tracker and all
