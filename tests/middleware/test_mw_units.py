"""Pure parts of the middleware: secrets, tokens, the robots and catalogue documents, spec rendering, state
mapping and the 5G-ERA plan view."""

from __future__ import annotations

import asyncio
import os

import pytest
from netapp_middleware.action_plan import plan_view, service_status
from netapp_middleware.auth import AuthError, RobotRegistry, TokenSigner, hash_secret, parse_robots, verify_secret
from netapp_middleware.backends.base import DEPLOYING, FAILED, READY, InstanceState
from netapp_middleware.backends.kubernetes import netapp_manifest, state_of
from netapp_middleware.backends.local import netapp_command, netapp_env
from netapp_middleware.catalogue import (
    DEFAULT_CATALOGUE,
    OBJECT_DETECTION_TASK_ID,
    parse_catalogue,
    placement_spec,
    render_spec,
)
from netapp_middleware.deployments import Registry, instance_name

from tests.middleware.mw_helpers import NullBackend


def test_secret_hash_round_trip_and_no_plain_text() -> None:
    hashed = hash_secret("s3cret", n=2**10)
    assert "s3cret" not in hashed and hashed.startswith("scrypt$1024$8$1$")
    assert verify_secret("s3cret", hashed)
    assert not verify_secret("s3cret!", hashed)
    assert hash_secret("s3cret", n=2**10) != hashed  # salted
    for bad in ("", "plain", "scrypt$x$8$1$a$b", "pbkdf2$1$2$3$4$5", "scrypt:1024:8:1:a:b"):
        assert not verify_secret("s3cret", bad)


def test_tokens_expire_and_cannot_be_forged() -> None:
    now = [1000.0]
    signer = TokenSigner(b"k" * 32, ttl_s=60, clock=lambda: now[0])
    token, claims = signer.issue("robot-1")
    assert signer.verify(token).robot_id == "robot-1" and claims.expires_at == 1060.0
    payload, signature = token.split(".")
    with pytest.raises(AuthError):
        TokenSigner(b"x" * 32).verify(token)  # another key
    forged = TokenSigner(b"x" * 32, clock=lambda: now[0]).issue("robot-2")[0].split(".")[0]
    with pytest.raises(AuthError):
        signer.verify(f"{forged}.{signature}")
    for garbage in ("", "abc", "a.b", f"{payload}."):
        with pytest.raises(AuthError):
            signer.verify(garbage)
    now[0] = 1060.0
    with pytest.raises(AuthError, match="expired"):
        signer.verify(token)


def test_robots_documents() -> None:
    h = hash_secret("x", n=2**10)
    assert parse_robots({"r1": h}) == {"r1": h}
    assert parse_robots({"robots": {"r1": h}}) == {"r1": h}
    assert parse_robots({"robots": [{"id": "r1", "secretHash": h}]}) == {"r1": h}
    assert parse_robots(None) == {}
    with pytest.raises(ValueError, match="scrypt"):
        parse_robots({"r1": "plain-text-secret"})
    with pytest.raises(ValueError):
        parse_robots([{"name": "r1"}])
    registry = RobotRegistry(lambda: {"r1": h})
    registry.authenticate("r1", "x")
    assert registry.known("r1") and not registry.known("r2")
    for robot, secret in (("r1", "y"), ("r2", "x")):
        with pytest.raises(AuthError):
            registry.authenticate(robot, secret)


def test_catalogue_parsing_and_task_ids() -> None:
    catalogue = parse_catalogue(DEFAULT_CATALOGUE)
    app = catalogue.get("object-detection")
    assert app is not None and app.task_id == OBJECT_DETECTION_TASK_ID
    assert catalogue.by_task_id(OBJECT_DETECTION_TASK_ID.upper()) is app
    assert catalogue.by_task_id("00000000-0000-0000-0000-000000000000") is None
    assert parse_catalogue({"apps": {"a": {"spec": {"image": "i"}}}}).get("a").task_id is None
    for bad, match in (
        ([], "map"),
        ({"a": {}}, "image"),
        ({"a": {"spec": {}}}, "image"),
        ({"a": {"image": "i"}}, "spec"),
        ({"a": {"spec": {"image": "i"}, "taskId": "nope"}}, "UUID"),
    ):
        with pytest.raises(ValueError, match=match):
            parse_catalogue(bad)


def test_placement_and_spec_rendering() -> None:
    assert placement_spec(None, None) == {"policy": "auto"}
    assert placement_spec({"policy": "edge", "requireGPU": True}, "cloud") == {"policy": "cloud", "requireGPU": True}
    assert placement_spec({"policy": "edge", "requireGPU": True}, None) == {"policy": "edge", "requireGPU": True}
    assert placement_spec({"policy": "auto"}, "edge-pool-1") == {"pool": "edge-pool-1"}
    app = parse_catalogue(DEFAULT_CATALOGUE).get("object-detection")
    spec = render_spec(app, "edge")
    assert spec["placement"] == {"policy": "edge"} and spec["model"]["url"].endswith("yolox_nano.onnx")
    assert app.spec["placement"] == {"policy": "auto"}  # the template is untouched
    manifest = netapp_manifest("n", "ns", spec, {"l": "v"})
    assert manifest["apiVersion"] == "netapp.dev/v1alpha1" and manifest["kind"] == "NetApp"
    assert manifest["metadata"] == {"name": "n", "namespace": "ns", "labels": {"l": "v"}, "annotations": {}}
    name = instance_name("Object_Detection")
    assert name.startswith("object-detection-") and len(name) <= 63


def test_state_of_netapp_status() -> None:
    assert state_of({"metadata": {"name": "a"}}) == InstanceState("Pending", message="waiting for the operator")
    ready = state_of(
        {
            "status": {
                "phase": "Ready",
                "url": "http://u:5896",
                "pool": "edge-1",
                "conditions": [
                    {"type": "Placed", "status": "True", "reason": "Scheduled", "message": "on edge-1"},
                    {"type": "Ready", "status": "True", "reason": "Available", "message": "1/1 replicas"},
                ],
            }
        }
    )
    assert ready == InstanceState("Ready", "http://u:5896", "edge-1", "Ready: Available: 1/1 replicas")
    failed = state_of(
        {
            "status": {
                "phase": "Failed",
                "conditions": [
                    {"type": "Placed", "status": "False", "reason": "NoPool", "message": "no pool has a GPU"}
                ],
            }
        }
    )
    assert failed.phase == "Failed" and failed.message == "Placed: NoPool: no pool has a GPU"
    deleting = state_of({"metadata": {"deletionTimestamp": "t"}, "status": {"phase": "Ready"}})
    assert deleting.message.startswith("being deleted")


def test_local_command_and_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NETAPP_MIDDLEWARE_TOKEN_KEY", "secret")
    spec = {
        "model": {"url": "https://x/m.onnx", "sha256": "ab", "timeoutSeconds": 30},
        "args": ["--conf", 0.3],
        "env": [{"name": "A", "value": "1"}],
    }
    assert netapp_command(spec, 9000, base=["py", "-m", "netapp", "serve"]) == [
        "py",
        "-m",
        "netapp",
        "serve",
        "--model",
        "https://x/m.onnx",
        "--sha256",
        "ab",
        "--download-timeout",
        "30",
        "--host",
        "127.0.0.1",
        "--port",
        "9000",
        "--conf",
        "0.3",
    ]
    assert netapp_command(spec, 1, base=["s"], model="/m.onnx")[1:5] == ["--model", "/m.onnx", "--host", "127.0.0.1"]
    assert "--model" not in netapp_command({}, 1, base=["s"])
    cameras = {"sources": [{"name": "door", "url": "rtsp://10.0.0.5/s"}], "args": ["--conf", "0.3"]}
    assert netapp_command(cameras, 1, base=["s"])[-4:] == ["--source", "door=rtsp://10.0.0.5/s", "--conf", "0.3"]
    env = netapp_env(spec, "od-1", "object-detection")
    assert env["A"] == "1" and env["NETAPP_ID"] == "od-1" and env["NETAPP_NAME"] == "object-detection"
    assert "NETAPP_MIDDLEWARE_TOKEN_KEY" not in env and env["PATH"] == os.environ["PATH"]


async def test_plan_view_shows_a_new_url_only_with_active() -> None:
    """era-5g-client would hang on a new serviceUrl that is not Active (see action_plan.plan_view)."""
    registry = Registry(NullBackend())
    app = parse_catalogue(DEFAULT_CATALOGUE).get("object-detection")
    deployment = registry.create("robot-1", app, None, True, meta={"taskId": app.task_id, "robotId": "r"})
    name = deployment.instance.name
    service = lambda: plan_view(deployment)["actionSequence"][0]["Services"][0]  # noqa: E731
    assert (service()["serviceStatus"], service()["serviceUrl"]) == ("Instantiating", "")
    registry.report(name, InstanceState(READY, "http://a:1", "edge-1"))
    assert (service()["serviceStatus"], service()["serviceUrl"]) == ("Active", "http://a:1")
    registry.report(name, InstanceState(DEPLOYING, "http://b:2", "cloud-1"))  # a failover in progress
    assert (service()["serviceStatus"], service()["serviceUrl"]) == ("Instantiating", "http://a:1")
    registry.report(name, InstanceState(READY, "http://b:2", "cloud-1"))
    assert (service()["serviceStatus"], service()["serviceUrl"]) == ("Active", "http://b:2")
    assert plan_view(deployment)["ActionPlanId"] == deployment.id
    assert service_status(FAILED) == "Problem"
    await asyncio.sleep(0)  # let the registry's create task finish


def test_the_robot_side_needs_no_server_code() -> None:
    """netapp.client.middleware runs on a robot with only `requests` installed."""
    import subprocess
    import sys

    code = (
        "import sys, netapp.client.middleware; "
        "heavy = {'fastapi', 'uvicorn', 'onnxruntime', 'kubernetes', 'kubernetes_asyncio', 'netapp_middleware', "
        "'netapp.server'}; "
        "print(sorted(heavy & set(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("placement", [None, "edge", "cloud", "auto", "edge-pool-1"])
def test_the_default_catalogue_makes_netapps_the_crd_and_the_operator_accept(placement: str | None) -> None:
    """Every spec the middleware creates is valid for the NetApp CRD's schema and for the operator's checks."""
    jsonschema = pytest.importorskip("jsonschema")
    from netapp_operator.spec import parse

    from tests.support.kube_emulator import load_crds

    (crd,) = [c for c in load_crds() if c["spec"]["names"]["plural"] == "netapps"]
    (version,) = [v for v in crd["spec"]["versions"] if v["name"] == "v1alpha1"]
    schema = version["schema"]["openAPIV3Schema"]["properties"]["spec"]
    spec = render_spec(parse_catalogue(DEFAULT_CATALOGUE).get("object-detection"), placement)
    jsonschema.validate(spec, schema)
    assert parse(spec).problems == ()


class _RecordingBackend(NullBackend):
    def __init__(self) -> None:
        self.created: list[tuple[str, str | None]] = []
        self.deleted: list[str] = []

    async def create(self, name, app, placement, spec, labels, annotations=None):
        self.created.append((name, placement))

    async def delete(self, name):
        self.deleted.append(name)


async def test_move_is_make_before_break_and_the_version_only_grows() -> None:
    backend = _RecordingBackend()
    registry = Registry(backend)
    app = parse_catalogue(DEFAULT_CATALOGUE).get("object-detection")
    deployment = registry.create("robot-1", app, "edge", False)
    old = deployment.instance
    registry.report(old.name, InstanceState(READY, "http://edge:1", "edge"))
    before = deployment.version
    waiter = asyncio.ensure_future(registry.wait("robot-1", deployment.id, before, 30.0))
    mover = asyncio.ensure_future(registry.move(deployment, app, "cloud", 30.0))
    await asyncio.sleep(0.01)
    (new_name, placement) = backend.created[-1]
    assert placement == "cloud" and not waiter.done()
    assert deployment.view()["url"] == "http://edge:1"  # the new one is not Ready: the robot stays
    registry.report(new_name, InstanceState(READY, "http://cloud:2", "cloud"))
    assert await mover is old and deployment.placement == "cloud"
    view = (await waiter).view()
    assert view["url"] == "http://cloud:2" and view["version"] > before
    assert backend.deleted == []  # the caller releases the old one once the robot has moved
    await registry.release(deployment, old)
    assert backend.deleted == [old.name] and deployment.version > before


async def test_a_move_whose_new_netapp_fails_leaves_the_robot_where_it_is() -> None:
    backend = _RecordingBackend()
    registry = Registry(backend)
    app = parse_catalogue(DEFAULT_CATALOGUE).get("object-detection")
    deployment = registry.create("robot-1", app, "edge", False)
    registry.report(deployment.instance.name, InstanceState(READY, "http://edge:1", "edge"))
    mover = asyncio.ensure_future(registry.move(deployment, app, "cloud", 30.0))
    await asyncio.sleep(0.01)
    new_name = backend.created[-1][0]
    registry.report(new_name, InstanceState(FAILED, message="no cloud pool"))
    assert await mover is None
    assert deployment.view()["url"] == "http://edge:1" and deployment.placement == "edge"
    assert backend.deleted == [new_name]


async def test_a_hedged_deployment_is_ready_with_every_url_and_survives_a_restart() -> None:
    from netapp_middleware.backends.base import Recovered

    registry = Registry(_RecordingBackend())
    app = parse_catalogue(DEFAULT_CATALOGUE).get("object-detection")
    deployment = registry.create("robot-1", app, None, True, hedge=["edge", "cloud", "edge"])
    edge, cloud = deployment.instances
    assert (edge.placement, cloud.placement, deployment.placement) == ("edge", "cloud", "edge")
    registry.report(cloud.name, InstanceState(READY, "http://cloud:2", "cloud"))
    assert deployment.view()["status"] == "Pending"  # waits for both
    registry.report(edge.name, InstanceState(FAILED, message="no edge pool"))
    view = deployment.view()
    assert (view["status"], view["url"], view["urls"]) == ("Ready", "http://cloud:2", ["http://cloud:2"])
    assert "one failed: no edge pool" in view["message"]
    registry.report(edge.name, InstanceState(READY, "http://edge:1", "edge"))
    assert deployment.view()["urls"] == ["http://edge:1", "http://cloud:2"]
    # A restarted middleware finds the two NetApps and rebuilds the one deployment, primary first.
    claim = deployment.claim()

    class Survivors(NullBackend):
        async def start(self, report):
            return [Recovered(i.name, app.name, i.placement, True, i.state, (claim,)) for i in (cloud, edge)]

    restarted = Registry(Survivors())
    await restarted.start()
    again = restarted.get("robot-1", deployment.id)
    assert [i.placement for i in again.instances] == ["edge", "cloud"]
    assert again.view()["urls"] == ["http://edge:1", "http://cloud:2"]
    await asyncio.sleep(0)


async def test_the_dashboard_lists_a_hedged_robot_on_each_of_its_netapps() -> None:
    registry = Registry(_RecordingBackend())
    app = parse_catalogue(DEFAULT_CATALOGUE).get("object-detection")
    deployment = registry.create("robot-1", app, None, True, hedge=["edge", "cloud"])
    edge, cloud = deployment.instances
    registry.report(edge.name, InstanceState(READY, "http://edge:1", "edge"))
    registry.report(cloud.name, InstanceState(READY, "http://cloud:2", "cloud"))
    overview = registry.overview()
    assert {n["url"]: n["robots"] for n in overview["netapps"]} == {
        "http://edge:1": ["robot-1"],
        "http://cloud:2": ["robot-1"],
    }
    assert [d["id"] for d in overview["robots"]["robot-1"]] == [deployment.id]
    await asyncio.sleep(0)


async def test_a_robot_that_leaves_during_a_move_leaves_no_netapp_behind() -> None:
    backend = _RecordingBackend()
    registry = Registry(backend)
    app = parse_catalogue(DEFAULT_CATALOGUE).get("object-detection")
    deployment = registry.create("robot-1", app, "edge", False)
    registry.report(deployment.instance.name, InstanceState(READY, "http://edge:1", "edge"))
    mover = asyncio.ensure_future(registry.move(deployment, app, "cloud", 30.0))
    await asyncio.sleep(0.01)
    new_name = backend.created[-1][0]
    await registry.delete("robot-1", deployment.id)
    registry.report(new_name, InstanceState(READY, "http://cloud:2", "cloud"))
    assert await mover is None
    assert sorted(backend.deleted) == sorted([deployment.instance.name, new_name])
