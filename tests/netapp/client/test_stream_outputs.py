"""`netapp stream --save/--jsonl`: the saved video shows each result's boxes where its detections were; the summary
names the transport, frame size and processor and splits the latency; `--show` without a display is one line."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from netapp.cli import main as netapp_main
from netapp.client.draw import class_colour


def edge_matches(frame: np.ndarray, detection: dict, tolerance: float = 60.0) -> float:
    """The share of the box's left and right edges (middle half, clear of the label) drawn in the class colour."""
    x1, y1, x2, y2 = (int(round(v)) for v in detection["bbox"])
    colour = np.array(class_colour(detection["class"]), float)
    rows = range(y1 + (y2 - y1) // 4, y2 - (y2 - y1) // 4)
    hits = 0
    for x in (x1, x2):
        for y in rows:
            patch = frame[y, max(0, x - 1) : x + 2].astype(float)
            hits += np.linalg.norm(patch - colour, axis=1).min() < tolerance
    return hits / (2 * len(rows))


def stream_and_save(url: str, source: Path, tmp_path: Path, capsys, *extra: str) -> tuple[dict, list, list]:
    video, lines = tmp_path / "out.mp4", tmp_path / "results.jsonl"
    code = netapp_main(
        ["stream", url, "--source", str(source), "--fps", "10", "--duration", "1.5"]
        + ["--save", str(video), "--jsonl", str(lines), "--json", *extra]
    )
    out = capsys.readouterr()
    assert code == 0, out.err
    summary = json.loads(out.out)
    records = [json.loads(line) for line in lines.read_text().splitlines()]
    capture = cv2.VideoCapture(str(video))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    return summary, records, frames


def check_boxes_drawn(source: Path, records: list, frames: list) -> None:
    original = cv2.imread(str(source))
    assert len(frames) == len(records) > 0  # one video frame per result
    for record, frame in zip(records, frames, strict=True):
        assert frame.shape == original.shape
        assert record["detections"]
        for detection in record["detections"]:
            if detection["score"] < 0.5:
                continue  # a weak box may lie under a stronger one's edge
            assert edge_matches(frame, detection) > 0.8, detection
            assert edge_matches(original, detection) < 0.2  # the colour is the drawing, not the picture


def test_save_draws_the_tiny_models_box_where_it_was_found(tmp_path, capsys, tiny_server):
    source = tmp_path / "grey.png"
    cv2.imwrite(str(source), np.full((160, 160, 3), 90, np.uint8))
    summary, records, frames = stream_and_save(tiny_server.url, source, tmp_path, capsys, "--transport", "http")
    check_boxes_drawn(source, records, frames)
    assert records[0]["detections"][0]["bbox"] == pytest.approx([20, 40, 100, 120], abs=1)
    assert summary["frame_size"] == "160x160" and summary["transport"] == "http"
    assert summary["processor"].startswith("tiny_yolox onnxruntime")
    parts = summary["latency_breakdown_ms"]
    assert set(parts) == {"uplink", "queue", "inference", "downlink"} and parts["inference"] > 0
    for record in records:
        b = record["breakdown_ms"]
        assert b["total_ms"] == pytest.approx(record["latency_ms"], abs=0.02)
        parts_sum = b["uplink_ms"] + b["queue_ms"] + b["inference_ms"] + b["downlink_ms"]
        assert parts_sum == pytest.approx(b["total_ms"], abs=0.05)


def test_save_draws_the_dog_where_yolox_found_it(tmp_path, capsys, serve, real_model_path, media_dir):
    from netapp.models import Detector, DetectorConfig

    server = serve(Detector(DetectorConfig(str(real_model_path))))
    source = media_dir / "dog.jpg"
    summary, records, frames = stream_and_save(server.url, source, tmp_path, capsys)
    check_boxes_drawn(source, records, frames)
    assert "dog" in summary["detections"] and summary["transport"] == "ws"


def test_summary_says_no_results_rather_than_none(tiny_server, tmp_path, capsys):
    from netapp.client.stats import ClientStats, format_summary

    text = format_summary(ClientStats().summary(1.0))
    assert "no results" in text and "None" not in text


def test_show_without_a_display_is_one_clear_line(tiny_server, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    source = tmp_path / "grey.png"
    cv2.imwrite(str(source), np.full((64, 64, 3), 90, np.uint8))
    code = netapp_main(["stream", tiny_server.url, "--source", str(source), "--duration", "1", "--show"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and err == ["error: --show needs a display (DISPLAY is not set); use --save out.mp4 instead"]


def test_an_error_after_a_live_status_line_gets_its_own_line():
    import io

    from netapp.apps.streaming import Progress

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Terminal()
    progress = Progress(out)
    progress.update("deployment Pending: waiting for a node")
    progress.end()
    out.write("error: the deployment failed\n")
    assert out.getvalue().splitlines()[-1] == "error: the deployment failed"
    progress.update("[  1.0s] sent 10")
    progress.line("deployed object-detection on edge: http://10.0.0.1:30001")
    assert out.getvalue().endswith("\ndeployed object-detection on edge: http://10.0.0.1:30001\n")


def test_the_uplink_adapts_by_default_and_says_so(tmp_path, capsys, profiled_tiny_server):
    tiny_server = profiled_tiny_server
    source = tmp_path / "grey.png"
    cv2.imwrite(str(source), np.full((160, 160, 3), 90, np.uint8))
    summary, records, _ = stream_and_save(tiny_server.url, source, tmp_path, capsys, "--budget-ms", "200")
    adapt = summary["adapt"]
    assert adapt["latency_budget_ms"] == 200 and adapt["accuracy_floor"] == 0.9
    assert adapt["changes"][0]["reason"] == "start" and adapt["changes"][0]["t_s"] == 0
    assert 0 <= adapt["within_budget"] <= 1 and adapt["settings"]["jpeg_quality"] == records[-1]["sent"]["jpeg_quality"]
    assert [r["frame"] for r in records] == sorted(r["frame"] for r in records) and records[0]["sent"]["bytes"] > 0
    off, records, _ = stream_and_save(tiny_server.url, source, tmp_path, capsys, "--adapt", "off")
    assert "adapt" not in off and all("sent" not in r for r in records)
    from netapp.client.stats import format_summary

    assert "uplink adapts   budget 200 ms" in format_summary(summary) and "uplink adapts" not in format_summary(off)


def test_stream_sends_what_the_model_uses_unless_full_frames(tmp_path, capsys, tiny_server):
    source = tmp_path / "grey.png"
    cv2.imwrite(str(source), np.full((160, 160, 3), 90, np.uint8))
    for extra, sent in (((), "64x64"), (("--full-frames",), "160x160")):
        summary, records, _ = stream_and_save(tiny_server.url, source, tmp_path, capsys, *extra)
        assert summary["frame_size"] == "160x160" and summary["sent_size"] == sent
        assert records[0]["detections"][0]["bbox"] == pytest.approx([20, 40, 100, 120], abs=1)  # the robot's pixels


def test_jsonl_carries_masks_and_keypoints_and_save_draws_them(tmp_path, capsys, serve):
    from netapp.client.draw import MASK_ALPHA
    from tests.support.result_processors import DOG, SceneProcessor, dog_box, scene

    server = serve(SceneProcessor())
    source = tmp_path / "grey.png"
    cv2.imwrite(str(source), np.full((240, 320, 3), 90, np.uint8))
    _, records, frames = stream_and_save(server.url, source, tmp_path, capsys, "--transport", "frames")
    expected = scene(320, 240)
    assert records and all(r["detections"] == expected["detections"] for r in records)  # as they came
    assert records[0]["output"] == {"classifications": expected["classifications"]}
    x1, y1, x2, y2 = dog_box(320, 240)
    fill = MASK_ALPHA * np.array(class_colour(DOG)) + (1 - MASK_ALPHA) * 90
    for frame in frames:  # mp4v is lossy: near the blend, far from the grey
        centre = frame[int((y1 + y2) / 2), int((x1 + x2) / 2)].astype(float)
        assert np.abs(centre - fill).max() < 25 and np.abs(centre - 90).max() > 40


def test_frames_in_flight_outlive_a_slow_netapp():
    from netapp.apps.streaming import FrameMemory
    from netapp.client.frames import SourceFrame

    memory = FrameMemory(4)
    frames = {t: SourceFrame(t) for t in range(20)}
    for t in range(20):  # frames 0 and 1 in flight; 2..19 offered while the netapp takes seconds a frame
        memory.keep(t, frames[t])
    assert memory.take(0) is frames[0] and memory.take(1) is frames[1]  # their results still find their frames
    assert memory.take(18) is None and memory.take(19) is frames[19]  # 18 was superseded by 19
    memory.keep(20, frames[0])
    assert memory.take(20) is frames[0] and memory.take(5) is None  # older than an answered one: gone
