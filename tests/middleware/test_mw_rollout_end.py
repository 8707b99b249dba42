"""A rollout's verdict outlives its netapp (issue 44, item 1): when the robots leave (the NetApp deleted, or asleep
after `idleToZero`) before the rollout has a verdict, the middleware keeps and logs one line saying there is none
and what had been seen; on Kubernetes, from the NetApp's `status.rollout` once the NetApp is deleted."""

from __future__ import annotations

import copy
import logging
from pathlib import Path
from typing import Any

import cv2
import onnx
import pytest
import yaml
from netapp_middleware.backends.kubernetes import KubernetesBackend
from netapp_middleware.backends.local import LocalBackend
from netapp_middleware.catalogue import DEFAULT_CATALOGUE, parse_catalogue
from netapp_middleware.rollouts import final_record, no_verdict
from netapp_middleware.sources import FileSource
from netapp_operator.constants import NETAPP_KIND
from netapp_operator.rollout_status import as_netapp_state

from netapp.client.middleware import MiddlewareClient
from tests.middleware.mw_helpers import DEADLINE_S, NS, ROBOTS, Operator, wait_until
from tests.support.rollout_robots import UNJUDGED_SPEED, Fleet

# A shadow that never decides within a test: an identical model, speed not judged, a window no test fills
ENDLESS = {"promoteAfter": 100000, "shadowSample": 1.0, "shadowBudget": 5, "maxSlowdown": UNJUDGED_SPEED}


def test_a_rollout_stopped_before_its_verdict_says_so_with_what_was_seen() -> None:
    seen = {"phase": "shadow", "model": "v2.onnx", "frames_compared": 17, "agreement": 0.0}
    seen["p95_ms"] = {"current": 131.0, "candidate": 812.4}
    assert no_verdict(seen) == (
        "no verdict: stopped after 17 frames compared, agreement 0.000, slowdown 6.20x (p95 812.4 ms against 131.0 ms)"
    )
    assert no_verdict({"phase": "shadow"}) == "no verdict: its netapp stopped before any frame was compared"
    stopped = final_record(seen, 1000.0)
    assert stopped["phase"] == "stopped" and stopped["reason"] == no_verdict(seen) and stopped["stopped_at"] == 1000.0
    decided = {"phase": "rolled_back", "reason": "agreement (F1) 0.000 ...", "frames_compared": 10}
    assert final_record(decided, 5.0) == {**decided, "stopped_at": 5.0}  # a verdict stays what it was
    status = {"phase": "Canary", "candidate": "v2.onnx", "framesCompared": 40, "agreement": "0.983", "errors": 0}
    status["p95Ms"] = {"current": 100.0, "candidate": 130.0}
    assert as_netapp_state(status) == {
        "phase": "canary",
        "model": "v2.onnx",
        "frames_compared": 40,
        "errors": 0,
        "agreement": 0.983,
        "p95_ms": {"current": 100.0, "candidate": 130.0},
    }
    assert as_netapp_state({"phase": "Pending", "agreement": "nonsense"}) == {"phase": "pending"}


@pytest.mark.parametrize("leaving", ["deleted", "asleep"])
def test_local_a_rollout_whose_robots_leave_before_its_verdict_is_kept_and_logged(
    leaving: str, start_middleware, real_model_path: Path, media_dir: Path, tmp_path: Path, caplog
) -> None:
    """A real middleware (local backend) and a real netapp process: a shadow under way when the robot leaves (its
    deployment deleted: the NetApp is stopped; or the app sleeps without robots) ends as `stopped`, with the frames,
    agreement and slowdown the netapp had seen just before, in `GET /apps/{app}/rollouts` and one log line."""
    caplog.set_level(logging.INFO, logger="netapp_middleware")
    catalogue = tmp_path / "catalogue.yaml"
    reexport = tmp_path / "yolox_nano_v2.onnx"
    onnx.save(onnx.load(str(real_model_path)), str(reexport))
    entry: dict[str, Any] = {"image": "netapp", "model": {"url": str(real_model_path)}}
    if leaving == "asleep":
        entry["scaling"] = {"idleToZero": "1s"}
    catalogue.write_text(yaml.safe_dump({"detect": {"spec": entry}}))
    backend = LocalBackend(ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, catalogue=FileSource(catalogue, parse_catalogue))
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("detect", timeout=2 * DEADLINE_S)
        name = mw.status(endpoint)["netapp"]
        fleet = Fleet(endpoint.url, cv2.imread(str(media_dir / "ped100.jpg")), robots=2)
        entry.update(model={"url": str(reexport)}, rollout=ENDLESS)
        catalogue.write_text(yaml.safe_dump({"detect": {"spec": entry}}))

        def compared() -> dict[str, Any] | None:
            rollouts = mw.rollouts("detect")
            return rollouts[0] if rollouts and (rollouts[0].get("frames_compared") or 0) >= 3 else None

        under_way = wait_until(compared, timeout=DEADLINE_S, what="frames compared")
        assert under_way["phase"] == "shadow", under_way
        fleet.finish()
        if leaving == "deleted":
            mw.delete(endpoint)
            wait_until(lambda: backend.pids() == {} or None, timeout=DEADLINE_S, what="the netapp stopped")
        else:
            wait_until(lambda: mw.status(endpoint)["status"] == "Idle", timeout=DEADLINE_S, what="the netapp asleep")

        def stopped() -> dict[str, Any] | None:
            rollouts = mw.rollouts("detect")
            return rollouts[0] if rollouts and rollouts[0]["phase"] == "stopped" else None

        state = wait_until(stopped, timeout=DEADLINE_S, what="the rollout's end")
    assert state["netapp"] == name and state["model"] == str(reexport), state
    assert state["frames_compared"] >= under_way["frames_compared"], (state, under_way)  # read at the stop
    reason = state["reason"]
    assert reason.startswith(f"no verdict: stopped after {state['frames_compared']} frames compared, "), reason
    assert "agreement 1.000, slowdown " in reason, reason
    lines = [r.getMessage() for r in caplog.records if "RolloutStopped" in r.getMessage()]
    assert lines == [f"NetApp {name}: RolloutStopped: detect: rollout of {reexport}: {reason}"], lines


def test_kubernetes_a_netapps_rollout_is_shown_and_kept_once_the_netapp_is_deleted(
    kube_api: Any, start_middleware: Any, caplog
) -> None:
    """The operator drives the rollout and writes `status.rollout`; the middleware shows it, and once the NetApp is
    deleted (its robot left, or someone deleted it) keeps its end: `stopped` and why, or the verdict it had."""
    caplog.set_level(logging.INFO, logger="netapp_middleware")
    server = start_middleware(KubernetesBackend(NS, kube_api.new_kube()), catalogue=copy.deepcopy(DEFAULT_CATALOGUE))
    operator = Operator(kube_api)
    app = "object-detection"

    def write_rollout(name: str, rollout: dict[str, Any]) -> None:
        kube_api.run(kube_api.kube.patch_status(NETAPP_KIND, NS, name, {"rollout": rollout}))

    def shown(name: str, phase: str) -> dict[str, Any] | None:
        return next((r for r in mw.rollouts(app) if r["netapp"] == name and r["phase"] == phase), None)

    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        view = mw.create(app)
        (name,) = wait_until(operator.netapps, what="the NetApp")
        operator.set_status(name, "Ready", "http://10.0.0.2:5896", "edge-1")
        shadow = {"phase": "Shadow", "candidate": "http://m/v2.onnx", "framesCompared": 12, "agreement": "0.983"}
        write_rollout(name, {**shadow, "p95Ms": {"current": 100.0, "candidate": 130.0}, "p95Ratio": 1.3})
        seen = wait_until(lambda: shown(name, "shadow"), what="the rollout shown")
        assert seen["frames_compared"] == 12 and seen["agreement"] == 0.983, seen
        mw.delete(view["id"])  # the robot leaves: the middleware deletes its NetApp
        state = wait_until(lambda: shown(name, "stopped"), what="the rollout's end")
        assert state["reason"] == (
            "no verdict: stopped after 12 frames compared, agreement 0.983, slowdown 1.30x (p95 130.0 ms against "
            "100.0 ms)"
        ), state

        view = mw.create(app)
        (other,) = wait_until(lambda: [n for n in operator.netapps() if n != name] or None, what="a second NetApp")
        write_rollout(other, {"phase": "Promoted", "candidate": "http://m/v2.onnx", "framesCompared": 200})
        wait_until(lambda: shown(other, "promoted"), what="the verdict shown")
        operator.delete(other)  # deleted outside the middleware: the watch says so
        kept = wait_until(lambda: next((r for r in mw.rollouts(app) if r["netapp"] == other), None), what="kept")
        wait_until(lambda: "stopped_at" in (shown(other, "promoted") or {}) or None, what="its end noted")
        assert kept["phase"] == "promoted" and kept["frames_compared"] == 200, kept
    lines = [r.getMessage() for r in caplog.records if "RolloutStopped" in r.getMessage()]
    assert lines == [f"NetApp {name}: RolloutStopped: {app}: rollout of http://m/v2.onnx: {state['reason']}"], lines
