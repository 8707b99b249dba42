"""Rollouts on a real netapp (uvicorn on loopback, onnxruntime, YOLOX-Nano): the canary, what `POST /rollout`
refuses, the live page. The candidates that agree, disagree, fail to load or are slow, with 8 robots streaming, are
in test_rollout_fleet.py."""

from __future__ import annotations

import threading

import cv2
import pytest
import requests

from netapp.cli import main
from netapp.models import Detector, DetectorConfig
from netapp.server.access import token_digest
from netapp.server.rollout.verdict import in_canary
from netapp.server.settings import Settings
from tests.support.rollout_robots import UNJUDGED_SPEED, Fleet, wait_for_verdict


@pytest.fixture
def image(media_dir):
    return cv2.imread(str(media_dir / "ped100.jpg"))


@pytest.fixture
def current(real_model_path):
    return Detector(DetectorConfig(str(real_model_path)))


def test_post_rollout_is_refused_on_an_open_netapp(serve, tiny_detector, tiny_model_path, capsys):
    server = serve(tiny_detector)
    body = {"candidate": str(tiny_model_path)}
    answer = requests.post(server.url + "/rollout", json=body, timeout=5)
    assert answer.status_code == 403 and "--token-file" in answer.text
    assert requests.get(server.url + "/rollout", timeout=5).json()["phase"] == "none"
    assert main(["rollout", "status", server.url]) == 0
    assert capsys.readouterr().out.strip() == "no rollout: serving tiny_yolox"
    assert main(["rollout", "status", "http://127.0.0.1:9"]) == 1  # nothing there: one line, exit 1


@pytest.mark.parametrize(
    "body, words",
    [
        (b"[1]", "JSON object"),
        (b'{"candidate": 3}', "candidate must be"),
        (b'{"candidate": "m.onnx", "promote_after": "x"}', "promote_after must be a whole number"),
        (b'{"candidate": "m.onnx", "max_slowdown": 0.5}', "max_slowdown must be 1 or more"),
        (b'{"candidate": "m.onnx", "shadow_sample": 0}', "shadow_sample must be above 0"),
        (b'{"candidate": "m.onnx", "surprise": 1}', "unknown field"),
        (b"{" * 5000, "over the 4096-byte limit"),
    ],
)
def test_post_rollout_refuses_bad_bodies_saying_what_is_wrong(serve, tiny_detector, body, words):
    settings = Settings(lanes=1)
    settings.token_sha256 = token_digest("admin")
    server = serve(tiny_detector, settings)
    answer = requests.post(server.url + "/rollout", data=body, headers={"Authorization": "Bearer admin"}, timeout=5)
    assert answer.status_code in (413, 422) and words in answer.text, answer.text
    assert requests.get(server.url + "/rollout", timeout=5).json()["phase"] == "none"
    assert "netapp_rollout_requests_refused_total{reason=" in requests.get(server.url + "/metrics", timeout=5).text


class CountingDetector(Detector):
    """YOLOX-Nano that counts the frames it answered for robots (on the inference threads), not in the shadow."""

    served = 0

    def process(self, batch):
        if threading.current_thread().name.startswith("netapp-infer"):
            CountingDetector.served += len(batch)
        return super().process(batch)


def test_a_canary_gives_its_share_of_robots_the_candidate_then_promotes(serve, current, real_model_path, image):
    settings = Settings(lanes=1)
    settings.token_sha256 = token_digest("admin")
    server = serve(current, settings)

    def counting(model, sha256):
        detector = CountingDetector(DetectorConfig(model))
        detector.load()
        return detector

    server.app.services.rollout.factory = counting
    CountingDetector.served = 0
    names = [f"robot-{i}" for i in range(50)]
    inside = [n for n in names if in_canary(n, 0.5)][:2]
    outside = [n for n in names if not in_canary(n, 0.5)][:2]
    fleet = Fleet(server.url, image, token="admin", robot_ids=inside + outside)
    body = {
        "candidate": str(real_model_path),
        **{"promote_after": 20, "window": 20, "max_slowdown": UNJUDGED_SPEED, "canary_share": 0.5},
        **{"shadow_sample": 0.5, "shadow_budget": 5},
    }
    answer = requests.post(server.url + "/rollout", json=body, headers={"Authorization": "Bearer admin"}, timeout=5)
    assert answer.status_code == 202, answer.text
    state = wait_for_verdict(server.url)
    fleet.finish()
    assert state["phase"] == "promoted" and "of the canary" in state["reason"], state
    assert state["canary_frames"] > 0 and CountingDetector.served >= state["canary_frames"]


def test_the_live_page_shows_the_rollout_and_its_reason(chromium, serve, tiny_model_path, tmp_path):
    truncated = tmp_path / "truncated.onnx"
    truncated.write_bytes(tiny_model_path.read_bytes()[:200])
    settings = Settings(lanes=1)
    settings.candidate = str(truncated)
    server = serve(Detector(DetectorConfig(str(tiny_model_path))), settings)
    wait_for_verdict(server.url)
    page = chromium.new_page()
    try:
        page.goto(server.url + "/ui")
        line = page.locator("#rollout")
        line.wait_for(state="visible", timeout=15_000)
        text = line.inner_text()
        assert "truncated.onnx: rolled_back" in text and "the candidate failed to load" in text, text
    finally:
        page.close()
