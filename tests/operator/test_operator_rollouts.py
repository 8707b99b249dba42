"""Model rollouts of a NetApp, the pure parts: which model it wants and serves, what its Deployment renders while
one is tried, which pod runs it, and its status, condition and Events from the netapp's GET /rollout."""

from __future__ import annotations

import datetime
import hashlib

import pytest
import yaml
from netapp_operator import render as renderer
from netapp_operator import rollout_status, rollouts
from netapp_operator.config import OperatorConfig
from netapp_operator.rollout_status import CONDITION
from netapp_operator.spec import parse

from netapp.protocol import ADMIN_TOKEN_DIGEST_ENV
from tests.operator.test_operator_render import kinds, netapp, pool
from tests.operator.test_operator_render import render as render_all
from tests.support.kube_emulator import CRD_DIR

NOW = datetime.datetime(2026, 11, 27, 14, 0, tzinfo=datetime.timezone.utc)
V1, V2 = {"url": "https://m/v1.onnx", "sha256": "a" * 64}, {"url": "https://m/v2.onnx"}
ROLLING = {"phase": "Shadow", "candidate": V2["url"], "target": V2, "pod": "det-edge-0"}


def placed(spec: dict, **status) -> dict:
    na = netapp(**spec)
    na["status"] = {"pool": "edge", "readyReplicas": 1, **status}
    return na


def test_the_wanted_model_is_the_candidate_else_the_model_else_the_default():
    assert rollouts.wanted_model({"model": {"url": V1["url"], "sha256": "A" * 64}}) == V1  # hex kept lower-case
    spec = {"model": V1, "rollout": {"candidate": V2["url"], "minAgreement": 0.9}}
    assert rollouts.wanted_model(spec) == V2
    volume = {"claimName": "models", "path": "v3.onnx"}
    assert rollouts.wanted_model({"model": {"volume": volume}}) == {"volume": volume}
    assert rollouts.wanted_model({}, "https://d/yolox.onnx") == {"url": "https://d/yolox.onnx"}
    assert rollouts.wanted_model({}) is None
    assert rollouts.wanted_model({"processor": "mine.module:Tracker", "model": V1}) is None  # its own weights


def test_the_request_comes_from_the_candidate_or_a_changed_model():
    assert rollouts.rollout_request({"model": V1}) == {"candidate": V1["url"], "sha256": "a" * 64}
    spec = {"model": V1, "rollout": {"candidate": V2["url"], "minAgreement": 0.9, "shadowSample": 0.5}}
    assert rollouts.rollout_request(spec) == {"candidate": V2["url"], "min_agreement": 0.9, "shadow_sample": 0.5}
    with pytest.raises(ValueError, match="spec.rollout.candidate or spec.model.url"):
        rollouts.rollout_request({})


@pytest.mark.parametrize(
    "spec, status, expected",
    [
        ({"model": V2}, {"model": V1}, True),  # a new model on a placed NetApp
        ({"model": V1}, {"model": V1}, False),  # it serves what it wants
        ({"model": V2}, {}, False),  # never placed with a model: the reconcile records one first
        ({"model": V2}, {"model": V1, "rollout": {**ROLLING, "phase": "RolledBack"}}, False),  # judged already
        ({"model": V2}, {"model": V1, "rollout": {**ROLLING, "target": {"url": "https://m/v0.onnx"}}}, True),
        ({"model": {"volume": {"claimName": "c", "path": "p"}}}, {"model": V1}, False),  # not in the running pods
        ({"model": V2}, {"model": V1, "readyReplicas": 0}, False),  # nothing serves: the pods take it at once
    ],
)
def test_a_rollout_runs_while_a_placed_netapp_wants_a_model_it_does_not_serve(spec, status, expected):
    na = placed(spec, **status)
    assert rollouts.active(na, rollouts.wanted_model(spec)) is expected


def test_status_model_is_recorded_once_then_changed_only_by_a_promotion_or_with_no_ready_replica():
    assert rollouts.model_to_record({}, 0, V1) == V1  # placed for the first time
    assert rollouts.model_to_record({"model": V1}, 2, V2) is ...  # a rollout decides
    assert rollouts.model_to_record({"model": V1}, 0, V2) == V2  # nothing to compare it with
    assert rollouts.model_to_record({"model": V1}, 0, V1) is ...


def test_the_deployment_renders_the_served_model_not_the_new_one_and_lets_the_operator_start_rollouts():
    config = OperatorConfig(rollout_token="s3cret")
    na = placed({"model": V2, "rollout": {"candidate": "https://m/v3.onnx"}}, model=V1)
    spec = rollouts.served_spec(parse(na["spec"]), na)
    [deployment, *_] = renderer.render(na, spec, pool(), config)
    [fetch] = deployment["spec"]["template"]["spec"]["initContainers"]
    env = {e["name"]: e.get("value") for e in fetch["env"]}
    assert env["MODEL_URL"] == V1["url"] and env["MODEL_SHA256"] == V1["sha256"]
    assert deployment["metadata"]["annotations"] == {"netapp.dev/model": f"{V1['url']}#sha256={V1['sha256']}"}
    [container] = deployment["spec"]["template"]["spec"]["containers"]
    digest = {e["name"]: e.get("value") for e in container["env"]}[ADMIN_TOKEN_DIGEST_ENV]
    assert digest == hashlib.sha256(b"s3cret").hexdigest()
    assert deployment["spec"]["strategy"]["rollingUpdate"]["maxUnavailable"] == 0  # a promotion drops no session
    # Without a token: no rollouts, nothing of them rendered.
    plain = kinds(render_all(netapp(model=V1), pool()))["Deployment"]
    assert "annotations" not in plain["metadata"]
    assert ADMIN_TOKEN_DIGEST_ENV not in str(plain)


def test_the_shadow_runs_on_the_first_ready_pod_of_the_deployment():
    labels = {"app.kubernetes.io/instance": "det", "netapp.dev/pool": "edge"}

    def pod(name, ready=True, pool="edge", ip="10.0.0.5", **meta):
        conditions = [{"type": "Ready", "status": "True" if ready else "False"}]
        return {
            "metadata": {"name": name, "labels": {**labels, "netapp.dev/pool": pool}, **meta},
            "status": {"phase": "Running", "podIP": ip, "conditions": conditions},
        }

    pods = [pod("det-edge-c"), pod("det-edge-a", ready=False), pod("det-cloud-a", pool="cloud"), pod("det-edge-b")]
    assert rollouts.ready_pod(pods, labels)["metadata"]["name"] == "det-edge-b"
    assert rollouts.ready_pod([pod("det-edge-b", deletionTimestamp="2026-11-27T14:00:00Z")], labels) is None
    assert rollouts.ready_pod([pod("det-edge-b", ip="")], labels) is None
    assert rollouts.pod_url(pod("p", ip="fd00::5"), 5896, tls=True) == "https://[fd00::5]:5896"


def test_status_from_the_netapps_answer_is_bounded_and_keeps_the_operators_fields():
    state = {
        "phase": "rolled_back",
        "frames_compared": 30,
        "agreement": 0.1234,
        "mask_iou": None,
        "oks": "nonsense",
        "p95_ms": {"current": 20.0, "candidate": 25.0},
        "errors": 0,
        "reason": "agreement (F1) 0.123 over 30 frames is below 0.95" + "x" * 1000,
    }
    new = rollout_status.from_state(ROLLING, state, NOW)
    assert new["phase"] == "RolledBack" and new["pod"] == "det-edge-0" and new["target"] == V2
    assert new["agreement"] == "0.123" and "maskIoU" not in new and "oks" not in new
    assert new["p95Ms"] == {"current": 20.0, "candidate": 25.0} and new["p95Ratio"] == 1.25
    assert len(new["reason"]) == 300 and new["finishedAt"] == "2026-11-27T14:00:00Z"
    assert rollout_status.from_state(ROLLING, {"phase": "weird", "frames_compared": True}, NOW)["phase"] == "Shadow"


def test_the_condition_and_events_say_what_is_served():
    running = rollout_status.condition([], ROLLING, V1, NOW)
    assert [(c["type"], c["status"]) for c in running] == [(CONDITION, "Unknown")]
    assert rollout_status.announcement(ROLLING, V1) is None
    promoted = {**ROLLING, "phase": "Promoted", "framesCompared": 200, "agreement": "1.000", "p95Ratio": 1.02}
    [cond] = rollout_status.condition(running, promoted, V2, NOW)
    assert cond["status"] == "True" and cond["reason"] == "Promoted"
    assert rollout_status.announcement(promoted, V1) == (
        "Normal",
        "RolloutPromoted",
        "https://m/v2.onnx promoted after 200 frames (agreement 1.000, p95 x1.02): new pods start with it",
    )
    back = {**ROLLING, "phase": "RolledBack", "reason": "the candidate failed on a frame"}
    [cond] = rollout_status.condition(running, back, V1, NOW)
    assert cond["status"] == "False" and f"the pods serve {V1['url']}" in cond["message"]
    kind, reason, message = rollout_status.announcement(back, V1)
    assert (kind, reason) == ("Warning", "RolloutRolledBack") and "\n" not in message
    assert message.startswith("https://m/v2.onnx rolled back: the candidate failed on a frame; the Deployment keeps")
    assert rollout_status.same({**back, "updatedAt": "a"}, {**back, "updatedAt": "b"})


def test_kubectl_get_netapp_prints_the_rollouts_phase_and_agreement():
    crd = yaml.safe_load((CRD_DIR / "netapps.netapp.dev.yaml").read_text())
    [version] = crd["spec"]["versions"]
    columns = {c["name"]: c["jsonPath"] for c in version["additionalPrinterColumns"]}
    assert columns["Rollout"] == ".status.rollout.phase" and columns["Agreement"] == ".status.rollout.agreement"
    status = version["schema"]["openAPIV3Schema"]["properties"]["status"]["properties"]
    assert set(status["rollout"]["properties"]["phase"]["enum"]) == {"Pending", *rollout_status.PHASES.values()}
    spec = version["schema"]["openAPIV3Schema"]["properties"]["spec"]["properties"]["rollout"]["properties"]
    assert set(spec) == {"candidate", "sha256", *rollouts.FIELDS}  # every field the request builder sends
