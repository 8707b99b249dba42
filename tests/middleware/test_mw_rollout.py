"""The local backend changes a running NetApp's model without a restart: the new model is shadowed on the running
netapp process (POST /rollout with the admin token the backend made for it), compared, and promoted or rolled back,
while robots stream."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import onnx
import pytest
import requests
from netapp_operator.rollouts import rollout_request

from tests.middleware.mw_helpers import Kubelet
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
