"""`McapRecorder` from robot code and `--mcap` for a video or image source: frames stamped with their capture time,
raw frames JPEG-encoded, the tracking netapp's track id in each detection's `id`."""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pytest

pytest.importorskip("mcap_ros2")

from netapp.cli import main as netapp_main  # noqa: E402
from netapp.client.delivery import Result  # noqa: E402
from netapp.ros.recorder import McapRecorder  # noqa: E402
from tests.support.bags import read_mcap, stamp_ns  # noqa: E402


def test_robot_code_records_frames_and_results_with_track_ids(tmp_path):
    out = tmp_path / "robot.mcap"
    frame = np.full((48, 64, 3), 120, np.uint8)
    detections = [{"bbox": [4, 8, 20, 40], "score": 0.9, "class": 2, "class_name": "car", "track_id": 7}]
    with McapRecorder(str(out)) as recording:
        for i in range(3):
            result = Result(1_000 + i, detections, 12.5, message={}, source="http://edge", source_stamp_ns=5_000 + i)
            recording.add(frame, result)
    topics = read_mcap(out)
    assert [t for t, _ in topics["/netapp/detections"]] == [5_000, 5_001, 5_002]
    _, array = topics["/netapp/detections"][0]
    detection = array.detections[0]
    assert detection.id == "7" and detection.results[0].hypothesis.class_id == "car"
    assert (detection.bbox.size_x, detection.bbox.size_y) == (16, 32)
    _, image = topics["/netapp/image"][0]
    assert image.format == "jpeg"
    decoded = cv2.imdecode(np.frombuffer(bytes(image.data), np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == frame.shape and abs(int(decoded.mean()) - 120) <= 2
    _, latency = topics["/netapp/latency"][0]
    assert latency.latency_ms == 12.5 and latency.source == "http://edge" and latency.inference_ms == 0
    assert "#7" in topics["/netapp/annotations"][0][1].texts[0].text


def test_an_image_source_is_stamped_with_its_capture_time(tmp_path, capsys, tiny_server):
    image, lines, out = tmp_path / "grey.png", tmp_path / "results.jsonl", tmp_path / "out.mcap"
    cv2.imwrite(str(image), np.full((160, 160, 3), 90, np.uint8))
    before = time.time_ns()
    argv = ["stream", tiny_server.url, "--source", str(image), "--fps", "10", "--duration", "1", "--transport", "http"]
    assert netapp_main(argv + ["--jsonl", str(lines), "--mcap", str(out)]) == 0
    capsys.readouterr()
    stamps = [json.loads(line)["source_stamp_ns"] for line in lines.read_text().splitlines()]
    assert stamps and all(before <= s <= time.time_ns() for s in stamps) and stamps == sorted(stamps)
    topics = read_mcap(out)
    for topic in ("/netapp/image", "/netapp/detections", "/netapp/annotations", "/netapp/latency"):
        assert [t for t, _ in topics[topic]] == stamps, topic
    assert [stamp_ns(a.header.stamp) for _, a in topics["/netapp/detections"]] == stamps
