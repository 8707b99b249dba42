"""Rollouts that decide as soon as the evidence does, and fairly, on a real netapp (uvicorn on loopback,
onnxruntime, the shared exports) with robots streaming: an identical model served in batches is promoted, not rolled
back for slowness; a garbage candidate is rolled back within a few frames, not a window; a rollout whose netapp
stops gets its verdict, logged."""

from __future__ import annotations

import logging

import cv2
import requests

from netapp.models import Detector, DetectorConfig
from netapp.server.access import token_digest
from netapp.server.settings import Settings
from tests.support.exports import export_path
from tests.support.polling import wait_until
from tests.support.rollout_robots import Fleet, reexport, wait_for_verdict

ADMIN = "admin"


def start_rollout(server, candidate, **policy) -> None:
    body = {"candidate": str(candidate), **policy}
    answer = requests.post(server.url + "/rollout", json=body, headers={"Authorization": f"Bearer {ADMIN}"}, timeout=5)
    assert answer.status_code == 202, answer.text


def admin_settings() -> Settings:
    settings = Settings(lanes=1)
    settings.token_sha256 = token_digest(ADMIN)
    return settings


def test_an_identical_model_served_in_batches_is_promoted_not_rolled_back_for_slowness(serve, media_dir, tmp_path):
    """Six robots at once: the lane runs batches of several frames, each frame's share of a batch far below one
    frame alone. The candidate (the same weights, saved again) is timed against the current model on the same
    thread, so the default --max-slowdown 1.5 holds."""
    model = export_path("yolo11n")
    server = serve(Detector(DetectorConfig(str(model))), admin_settings())
    fleet = Fleet(server.url, cv2.imread(str(media_dir / "ped100.jpg")), token=ADMIN, robots=6)
    try:
        start_rollout(server, reexport(model, tmp_path / "yolo11n_again.onnx"), promote_after=20, shadow_sample=0.5,
                      shadow_budget=5)  # fmt: skip
        state = wait_for_verdict(server.url)
        fleet.finish()
    finally:
        fleet.stop.set()
    assert state["phase"] == "promoted", state
    p95 = state["p95_ms"]
    assert p95["candidate"] < 1.5 * p95["current"], p95


def test_a_garbage_candidate_is_rolled_back_within_a_few_frames_not_a_window(serve, real_model_path, tiny_model_path,
                                                                             media_dir):  # fmt: skip
    server = serve(Detector(DetectorConfig(str(real_model_path))), admin_settings())
    fleet = Fleet(server.url, cv2.imread(str(media_dir / "ped100.jpg")), token=ADMIN, robots=2)
    try:
        start_rollout(server, tiny_model_path, promote_after=200, shadow_sample=1, shadow_budget=5)  # window 50
        state = wait_for_verdict(server.url)
    finally:
        fleet.stop.set()
    assert state["phase"] == "rolled_back" and "beyond doubt" in state["reason"], state
    assert state["frames_compared"] <= 10, state


def test_a_rollout_whose_netapp_stops_gets_its_verdict_logged(serve, real_model_path, media_dir, caplog):
    server = serve(Detector(DetectorConfig(str(real_model_path))), admin_settings())
    fleet = Fleet(server.url, cv2.imread(str(media_dir / "ped100.jpg")), token=ADMIN, robots=1)
    try:
        start_rollout(server, real_model_path, promote_after=100_000, shadow_sample=1, shadow_budget=5)
        rollout = server.app.services.rollout
        wait_until(lambda: rollout.stats.frames >= 3, what="three frames compared")
    finally:
        fleet.stop.set()
    with caplog.at_level(logging.INFO, logger="netapp.server.rollout.rollout"):
        server.stop()  # the robots left: the local backend stops an idle netapp
    assert rollout.phase == "rolled_back" and rollout.reason.startswith("the netapp stopped before a verdict: ")
    assert "frames compared, agreement (F1) 1.000" in rollout.reason
    lines = [r.getMessage() for r in caplog.records if r.name == "netapp.server.rollout.rollout"]
    assert any("rolled_back (the netapp stopped before a verdict" in line for line in lines), lines


def test_a_shadow_starved_by_its_budget_says_so_with_the_time_to_a_verdict(serve, real_model_path, media_dir, caplog):
    """The default budget (the shadow at most 0.1 of the current model's time) with every frame sampled: most are
    skipped, and GET /rollout and one log line say so, with the pace and the flag that would shorten it."""
    caplog.set_level(logging.WARNING, logger="netapp.server.rollout.rollout")
    server = serve(Detector(DetectorConfig(str(real_model_path))), admin_settings())
    fleet = Fleet(server.url, cv2.imread(str(media_dir / "ped100.jpg")), token=ADMIN, robots=2)
    try:
        start_rollout(server, real_model_path, promote_after=1000, shadow_sample=1)

        def noted() -> dict | None:
            state = requests.get(server.url + "/rollout", timeout=5).json()
            return state if state["note"] and state["verdict_in_s"] else None

        state = wait_until(noted, what="the budget's note")
    finally:
        fleet.stop.set()
    assert state["skipped"]["budget"] > state["frames_compared"] >= 1, state
    assert "the shadow budget (0.1 of the current model's time) skipped" in state["note"]
    assert "a larger --shadow-budget (shadowBudget) decides sooner" in state["note"]
    told = [r.getMessage() for r in caplog.records if "the shadow budget" in r.getMessage()]
    assert len(told) == 1, told
