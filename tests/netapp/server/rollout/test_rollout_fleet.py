"""The issue's rollouts at full size: one real netapp (uvicorn on loopback, onnxruntime, YOLOX-Nano) serves 8 robots
streaming over HTTP, Socket.IO and `frames` (JPEG and H.264) while four candidates are tried on it in turn, each
started over `POST /rollout` as an admin would:

- YOLOX-Nano converted to FP16 (float inputs and outputs kept): the same model at another precision, which agrees
  (F1 0.999 against FP32 on 60 frames of the shared media, checked first) and is promoted with no flag;
- a model whose answers are garbage, one that fails to load, and one 3x slower: each rolled back with its reason.

The robots stream throughout; at the end their own counters show no error and no frame lost.
(An int8 dynamic quantization of YOLOX-Nano was measured too and does not agree, F1 0.0: not a candidate that
should pass.)"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import onnx
import pytest
import requests

from netapp.cli import main
from netapp.models import Detector, DetectorConfig
from netapp.server.access import token_digest
from netapp.server.app import create_app
from netapp.server.runner import uvicorn_options
from netapp.server.settings import Settings
from tests.support.rollout_robots import UNJUDGED_SPEED, Fleet, wait_for_verdict
from tests.support.servers import BackgroundServer

ADMIN = "admin"
QUICK = {"promote_after": 20, "window": 20, "shadow_sample": 0.5, "shadow_budget": 5}  # a test's pace


@pytest.fixture(scope="module")
def fp16_model(real_model_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """YOLOX-Nano with FP16 weights and arithmetic, its float32 input and outputs kept (built here, never kept)."""
    from onnxruntime.transformers.float16 import convert_float_to_float16

    path = tmp_path_factory.mktemp("fp16") / "yolox_nano_fp16.onnx"
    onnx.save(convert_float_to_float16(onnx.load(str(real_model_path)), keep_io_types=True), str(path))
    return path


def test_the_fp16_conversion_agrees_with_fp32_on_the_shared_media(real_model_path, fp16_model, media_dir):
    """Before it is a candidate that should pass: FP16 and FP32 answers, matched as the shadow matches them, on the
    shared pictures and every 5th frame of the pedestrians video (60 frames, about 1300 boxes: F1 0.999)."""
    from netapp.models.matching import agreement_f1

    frames = [cv2.imread(str(media_dir / name)) for name in ("ped100.jpg", "dog.jpg")]
    video = cv2.VideoCapture(str(media_dir / "pedestrians.avi"))
    for index in range(290):
        ok, frame = video.read()
        if not ok:
            break
        if index % 5 == 4:
            frames.append(frame)
    video.release()
    detectors = [Detector(DetectorConfig(str(path))) for path in (real_model_path, fp16_model)]
    for detector in detectors:
        detector.load()
    fp32, fp16 = ([d.detect(frame) for frame in frames] for d in detectors)
    assert len(frames) == 60 and sum(map(len, fp32)) > 1000
    assert agreement_f1(fp32, fp16) >= 0.99


@pytest.fixture(scope="module")
def fleet_netapp(real_model_path: Path, media_dir: Path) -> Iterator[tuple[BackgroundServer, Fleet]]:
    """The netapp and its 8 robots, streaming from the first test of this module to its end; stopping them checks
    that they saw no error and lost no frame."""
    settings = Settings(lanes=1)
    settings.token_sha256 = token_digest(ADMIN)  # rollouts are an admin's (and robots present the same token)
    app = create_app(Detector(DetectorConfig(str(real_model_path))), settings)
    server = BackgroundServer(app, **uvicorn_options(settings)).start()
    fleet = Fleet(server.url, cv2.imread(str(media_dir / "ped100.jpg")), token=ADMIN)
    try:
        yield server, fleet
        fleet.finish()
    finally:
        fleet.stop.set()
        server.stop()


def roll_out(server: BackgroundServer, fleet: Fleet, candidate: Path, **policy: float) -> dict:
    """Start a rollout of `candidate`, wait for its verdict, and for every robot to stream on past it."""
    since = fleet.answered()
    body = {"candidate": str(candidate), **QUICK, **policy}
    answer = requests.post(server.url + "/rollout", json=body, headers={"Authorization": f"Bearer {ADMIN}"}, timeout=5)
    assert answer.status_code == 202, answer.text
    state = wait_for_verdict(server.url)
    fleet.streamed(since)
    return state


def serving(server: BackgroundServer) -> str:
    return requests.get(server.url + "/v2", timeout=5).json()["models"][0]["name"]


def test_the_model_at_another_precision_agrees_and_is_promoted_with_no_flag(fleet_netapp, fp16_model, capsys):
    server, fleet = fleet_netapp
    state = roll_out(server, fleet, fp16_model, max_slowdown=UNJUDGED_SPEED)
    assert state["phase"] == "promoted" and state["reason"].startswith("agreed on"), state
    assert state["agreement"] >= 0.95 and state["frames_compared"] >= 20 and state["errors"] == 0
    assert serving(server) == "yolox_nano_fp16"
    metrics = requests.get(server.url + "/metrics", timeout=5).text
    assert 'netapp_rollout_verdicts_total{verdict="promoted"} 1.0' in metrics
    assert 'netapp_rollout_phase{phase="promoted"} 1.0' in metrics
    assert main(["rollout", "status", server.url]) == 0  # what an operator types
    shown = capsys.readouterr().out
    assert "phase:      promoted" in shown and "serving:    yolox_nano_fp16" in shown


def test_a_candidate_whose_answers_are_garbage_is_rolled_back(fleet_netapp, tiny_model_path):
    server, fleet = fleet_netapp
    before = serving(server)
    state = roll_out(server, fleet, tiny_model_path)  # always one `robot` in a corner
    assert state["phase"] == "rolled_back" and "agreement (F1)" in state["reason"], state
    assert state["agreement"] < 0.5 and serving(server) == before


def test_a_candidate_that_crashes_on_load_is_rolled_back_and_the_netapp_serves_on(
    fleet_netapp, real_model_path, tmp_path
):
    server, fleet = fleet_netapp
    truncated = tmp_path / "truncated.onnx"
    truncated.write_bytes(real_model_path.read_bytes()[:100_000])
    state = roll_out(server, fleet, truncated)
    assert state["phase"] == "rolled_back" and state["reason"].startswith("the candidate failed to load"), state


class SlowDetector(Detector):
    """YOLOX-Nano taking 3 times as long: it sleeps twice its own inference."""

    def process(self, batch):
        started = time.perf_counter()
        results = super().process(batch)
        time.sleep(2 * (time.perf_counter() - started))
        return results


def test_a_3x_slower_candidate_is_rolled_back_for_its_p95(fleet_netapp, real_model_path):
    server, fleet = fleet_netapp
    rollout = server.app.services.rollout
    usual = rollout.factory

    def slow(model, sha256):
        detector = SlowDetector(DetectorConfig(model))
        detector.load()
        return detector

    rollout.factory = slow  # the netapp loads this candidate 3x slower than the same model it serves
    try:
        state = roll_out(server, fleet, real_model_path)
    finally:
        rollout.factory = usual
    assert state["phase"] == "rolled_back" and "slower on the median of" in state["reason"], state
    metrics = requests.get(server.url + "/metrics", timeout=5).text
    assert 'netapp_rollout_verdicts_total{verdict="rolled_back"} 3.0' in metrics
