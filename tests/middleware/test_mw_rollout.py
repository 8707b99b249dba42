"""The local backend changes a running NetApp's model without a restart: the new model is shadowed on the running
netapp process (POST /rollout with the admin token the backend made for it), compared, and promoted or rolled back,
while robots stream. The middleware does it when the catalogue changes an app's model: its outcome in
`GET /apps/{app}/rollouts` and one log line."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import cv2
import onnx
import pytest
import requests
import yaml
from netapp_middleware.backends.local import LocalBackend, refusal_in_spec_terms
from netapp_middleware.catalogue import parse_catalogue
from netapp_middleware.rollouts import candidate_key, outcome_event, rollout_request, serving_key
from netapp_middleware.sources import FileSource

from netapp.client.middleware import MiddlewareClient, MiddlewareError
from tests.middleware.mw_helpers import DEADLINE_S, ROBOTS, Kubelet, wait_until
from tests.support.rollout_robots import UNJUDGED_SPEED, Fleet, wait_for_verdict

QUICK = {"promoteAfter": 20, "shadowSample": 0.5, "shadowBudget": 5}  # a test's pace; the defaults are docs'


def test_the_rollout_request_comes_from_the_candidate_or_a_changed_model():
    assert rollout_request({"model": {"url": "http://m/v2.onnx", "sha256": "a" * 64}}) == {
        "candidate": "http://m/v2.onnx",
        "sha256": "a" * 64,
    }
    spec: dict[str, Any] = {"model": {"url": "v1.onnx"}, "rollout": {"candidate": "v2.onnx", "minAgreement": 0.9}}
    assert rollout_request(spec) == {"candidate": "v2.onnx", "min_agreement": 0.9}
    with pytest.raises(ValueError, match="spec.rollout.candidate or spec.model.url"):
        rollout_request({})


def test_a_spec_asks_for_its_candidate_else_its_model_and_a_verdict_is_one_line():
    spec: dict[str, Any] = {"model": {"url": "v1.onnx", "sha256": "a" * 64}}
    assert serving_key(spec) == candidate_key(spec) == ("v1.onnx", "a" * 64)  # nothing to roll out
    spec["rollout"] = {"candidate": "v2.onnx", "promoteAfter": 5}
    assert serving_key(spec) == ("v1.onnx", "a" * 64) and candidate_key(spec) == ("v2.onnx", "")
    assert serving_key({}) is None and candidate_key({"rollout": {}}) is None
    promoted = {"phase": "promoted", "model": "v2.onnx", "reason": "agreed on 5 frames", "agreement": 1.0}
    assert outcome_event("detect", promoted) == (
        "Normal",
        "RolloutPromoted",
        "detect: rollout of v2.onnx promoted: agreed on 5 frames (agreement 1.000)",
    )
    back = {"phase": "rolled_back", "model": "v2.onnx", "reason": "it crashed", "serving": "v1"}
    assert outcome_event("detect", back)[:2] == ("Warning", "RolloutRolledBack")
    assert outcome_event("detect", {"phase": "shadow"}) is None


@pytest.fixture
def kubelet(real_model_path: Path):
    kubelet = Kubelet(str(real_model_path))
    yield kubelet
    kubelet.close()


def test_a_changed_model_is_shadowed_on_the_running_netapp_and_promoted_without_a_restart(
    kubelet: Kubelet, real_model_path: Path, media_dir: Path, tmp_path: Path
) -> None:
    url = kubelet.serve("na-1")
    (pid,) = kubelet.backend.pids().values()
    reexport = tmp_path / "yolox_nano_v2.onnx"
    onnx.save(onnx.load(str(real_model_path)), str(reexport))
    fleet = Fleet(url, cv2.imread(str(media_dir / "ped100.jpg")))
    spec = {"model": {"url": str(reexport)}, "rollout": {**QUICK, "maxSlowdown": UNJUDGED_SPEED}}
    started = kubelet.runner.call(kubelet.backend.rollout("na-1", spec))
    assert started["phase"] == "shadow" and started["model"] == str(reexport)
    state = wait_for_verdict(url)
    fleet.finish()
    assert state["phase"] == "promoted" and state["agreement"] >= 0.95, state
    assert kubelet.runner.call(kubelet.backend.rollout_state("na-1"))["serving"] == "yolox_nano_v2"
    assert kubelet.backend.pids() == {"na-1": pid}  # the same process: nothing restarted


def test_a_rollout_needs_the_backends_admin_token_and_a_bad_candidate_is_rolled_back(
    kubelet: Kubelet, tmp_path: Path
) -> None:
    url = kubelet.serve("na-2")
    body = {"candidate": str(tmp_path / "none.onnx")}
    assert requests.post(url + "/rollout", json=body, timeout=5).status_code == 401  # only the backend may
    kubelet.runner.call(kubelet.backend.rollout("na-2", {"rollout": {"candidate": str(tmp_path / "none.onnx")}}))
    state = wait_for_verdict(url)
    assert state["phase"] == "rolled_back" and "does not exist" in state["reason"], state
    with pytest.raises(ValueError, match="no running netapp"):
        kubelet.runner.call(kubelet.backend.rollout("na-9", {"rollout": {"candidate": "x.onnx"}}))


def test_a_model_changed_in_the_catalogue_is_rolled_out_on_the_running_netapp(
    start_middleware, real_model_path: Path, tiny_model_path: Path, media_dir: Path, tmp_path: Path, caplog
) -> None:
    """A real middleware (local backend, its catalogue a file) and a real netapp process: a rollout the netapp
    refuses is said, a garbage candidate named in the catalogue is rolled back, then a changed `spec.model` is
    promoted; the same process all along, robots streaming throughout, each outcome in the app's rollouts and one
    log line."""
    caplog.set_level(logging.INFO, logger="netapp_middleware")
    catalogue = tmp_path / "catalogue.yaml"

    def publish(spec: dict[str, Any]) -> None:
        entry = {"image": "netapp", "model": {"url": str(real_model_path)}, **spec}
        catalogue.write_text(yaml.safe_dump({"detect": {"spec": entry}}))

    publish({})
    backend = LocalBackend(ready_timeout_s=2 * DEADLINE_S)  # no --model: each netapp serves its spec's
    server = start_middleware(backend, catalogue=FileSource(catalogue, parse_catalogue))
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("detect", timeout=2 * DEADLINE_S)
        name, pid = next(iter(backend.pids().items()))
        assert mw.status(endpoint)["netapp"] == name
        fleet = Fleet(endpoint.url, cv2.imread(str(media_dir / "ped100.jpg")), robots=4)
        assert mw.rollouts("detect") == []  # the catalogue names the model it serves
        with pytest.raises(MiddlewareError, match="no app 'nope' in the catalogue") as refused:
            mw.rollouts("nope")
        assert refused.value.status == 404

        def verdict(model: Path, phases: tuple[str, ...] = ("promoted", "rolled_back")) -> dict[str, Any]:
            def done() -> dict[str, Any] | None:
                rollouts = mw.rollouts("detect")
                decided = rollouts and rollouts[0]["model"] == str(model) and rollouts[0]["phase"] in phases
                return rollouts[0] if decided else None

            return wait_until(done, timeout=DEADLINE_S, what=f"the verdict on {model.name}")

        garbage = {"candidate": str(tiny_model_path), **QUICK}  # always one `robot` in a corner
        publish({"rollout": {**garbage, "maxSlowdown": 0.5}})  # a value the netapp refuses: said once
        state = verdict(tiny_model_path, ("refused",))
        assert "spec.rollout.maxSlowdown must be 1 or more" in state["reason"], state  # as the spec writes it
        assert "{" not in state["reason"] and "max_slowdown" not in state["reason"], state
        publish({"rollout": garbage})  # the entry fixed: tried again
        state = verdict(tiny_model_path)
        assert state["phase"] == "rolled_back" and "agreement (F1)" in state["reason"], state
        assert state["serving"] == "yolox_nano" and state["netapp"] == name

        reexport = tmp_path / "yolox_nano_v2.onnx"
        onnx.save(onnx.load(str(real_model_path)), str(reexport))
        publish({"model": {"url": str(reexport)}, "rollout": {**QUICK, "maxSlowdown": UNJUDGED_SPEED}})
        state = verdict(reexport)
        assert state["phase"] == "promoted" and state["serving"] == "yolox_nano_v2", state
        fleet.finish()
        assert backend.pids() == {name: pid}  # the same process: nothing restarted
    lines = [r.getMessage() for r in caplog.records if "detect: rollout of" in r.getMessage()]
    assert [line.split(": ")[1] for line in lines] == ["RolloutRefused", "RolloutRolledBack", "RolloutPromoted"], lines


def test_a_refused_rollout_names_the_field_as_the_spec_writes_it_in_one_line():
    from types import SimpleNamespace

    from netapp.server.settings import Policy

    body = {"error": Policy(max_slowdown=0.5).problem(), "reason": "invalid_request"}
    answer = SimpleNamespace(status_code=422, json=lambda: body, text=str(body))
    said = refusal_in_spec_terms(answer)
    assert said.startswith("spec.rollout.maxSlowdown must be 1 or more") and "{" not in said
    text_only = SimpleNamespace(status_code=502, json=lambda: json.loads("<html>"), text="<html>bad gateway")
    assert refusal_in_spec_terms(text_only) == "HTTP 502: <html>bad gateway"
