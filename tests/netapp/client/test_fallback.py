"""The robot's own processor (the fallback): real detection on the robot's thread, newest frame wins."""

from __future__ import annotations

import queue

import cv2
import numpy as np

from netapp.client.fallback import LOCAL, LocalFallback
from tests.support.images import make_jpeg
from tests.support.onnx_models import TINY_NAMES


def run(processor):
    results: queue.Queue = queue.Queue()
    errors: queue.Queue = queue.Queue()
    local = LocalFallback(processor, results.put, errors.put)
    local.start()
    return local, results, errors


def test_local_results_look_like_a_netapps(tiny_detector) -> None:
    local, results, errors = run(tiny_detector)
    try:
        local.submit(7, make_jpeg())
        result = results.get(timeout=10)
        assert result["timestamp"] == 7 and result["source"] == LOCAL
        assert result["detections"][0]["class_name"] == TINY_NAMES[2]
        assert result["timestamp_before_process"] <= result["timestamp_after_process"]
        image = cv2.imdecode(np.frombuffer(make_jpeg(), np.uint8), cv2.IMREAD_COLOR)
        local.submit(8, image)  # BGR frames too
        assert results.get(timeout=10)["timestamp"] == 8
        local.submit(9, b"not a jpeg")
        error = errors.get(timeout=10)
        assert error["timestamp"] == 9 and "could not decode" in error["error"] and error["source"] == LOCAL
    finally:
        local.close()


def test_newest_frame_wins_while_the_processor_is_busy(gated) -> None:
    gated.gate.set()  # the warm-up at start() goes through
    local, results, _ = run(gated)
    assert gated.entered.acquire(timeout=10) and gated.calls == 1 and local.expected_ms > 0
    gated.gate.clear()
    gated.calls = 0
    try:
        local.submit(1, make_jpeg())
        assert gated.entered.acquire(timeout=10)  # frame 1 holds the processor
        for ts in (2, 3, 4):
            local.submit(ts, make_jpeg())
        gated.gate.set()
        assert [results.get(timeout=10)["timestamp"] for _ in range(2)] == [1, 4]
        assert local.dropped == 2 and gated.calls == 2
    finally:
        local.close()
