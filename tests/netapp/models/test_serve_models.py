"""Every task through a real netapp on loopback, the robot's JPEG bytes to /send_image: masks, keypoints, oriented
boxes in the robot frame's own pixels, classifications in the result; and bad models refused by `netapp serve`
with one line, exit code 2, and nothing listening."""

from __future__ import annotations

import socket
import subprocess

import cv2
import numpy as np
import pytest
import requests

from netapp.models import Detector, DetectorConfig
from netapp.results import mask_to_array
from netapp.serve_process import free_port, serve_command
from tests.support.onnx_models import (
    POSE_POINTS,
    TINY_BOX,
    classifier_model,
    constant_model,
    obb_model,
    yolov8_model,
    yolov8_pose_model,
    yolov8_seg_model,
)

FRAME = np.full((96, 128, 3), 80, np.uint8)  # letterboxed into 64x64: x 0.5, 8 px of padding above and below


def result_for(server, frame: np.ndarray = FRAME) -> dict:
    """One JPEG, as a robot sends it, and its result."""
    sid = requests.post(f"{server.url}/register", json={}, timeout=5).json()["session_id"]
    jpeg = cv2.imencode(".jpg", frame)[1].tobytes()
    headers = {"X-Session-Id": sid, "Content-Type": "image/jpeg"}
    response = requests.post(
        f"{server.url}/send_image", params={"wait": "true"}, data=jpeg, headers=headers, timeout=30
    )
    assert response.status_code == 200, response.text
    return response.json()


def in_frame(x1, y1, x2, y2):
    return [x1 * 2, (y1 - 8) * 2, x2 * 2, (y2 - 8) * 2]


def test_segmentation_served(serve, tmp_path):
    server = serve(Detector(DetectorConfig(str(yolov8_seg_model(tmp_path / "seg.onnx", TINY_BOX)))))
    (d,) = result_for(server)["detections"]
    assert d["bbox"] == pytest.approx(in_frame(*TINY_BOX), abs=0.2) and d["class_name"] == "blob"
    mask = mask_to_array(d["mask"], 96, 128)
    ys, xs = np.nonzero(mask)
    x1, y1, x2, y2 = in_frame(*TINY_BOX)
    assert (
        abs(xs.min() - x1) <= 1
        and abs(xs.max() + 1 - x2) <= 1
        and abs(ys.min() - y1) <= 1
        and abs(ys.max() + 1 - y2) <= 1
    )


def test_pose_served(serve, tmp_path):
    server = serve(Detector(DetectorConfig(str(yolov8_pose_model(tmp_path / "pose.onnx", TINY_BOX)))))
    (d,) = result_for(server)["detections"]
    assert np.asarray(d["keypoints"]) == pytest.approx(
        np.asarray([[x * 2, (y - 8) * 2, v] for x, y, v in POSE_POINTS]), abs=0.05
    )


def test_oriented_boxes_served(serve, tmp_path):
    server = serve(Detector(DetectorConfig(str(obb_model(tmp_path / "obb.onnx", (32, 32, 20, 10, 0.5), 1)))))
    (d,) = result_for(server)["detections"]
    assert d["rbox"] == pytest.approx([64, 48, 40, 20, 0.5], abs=0.05) and d["class_name"] == "c1"
    x1, y1, x2, y2 = d["bbox"]
    assert x1 < 64 - 20 < 64 + 20 < x2 and y1 < 48 < y2  # the box around the turned one


def test_classification_served(serve, tmp_path):
    logits = [0.0, 3.0, 1.0, 2.0, -1.0, 0.5]
    server = serve(Detector(DetectorConfig(str(classifier_model(tmp_path / "cls.onnx", logits)))))
    result = result_for(server)
    assert result["detections"] == []
    top = result["classifications"]
    assert [c["class"] for c in top] == [1, 3, 2, 5, 0]
    probs = np.exp(logits) / np.exp(logits).sum()  # the graph has no softmax: the netapp applies it
    assert top[0]["score"] == pytest.approx(probs[1], abs=1e-4)


def test_detection_served(serve, tmp_path):
    path = yolov8_model(tmp_path / "v8.onnx", (0.0, 4.0, 70.0, 40.0), class_id=0)  # runs past the image's right
    server = serve(Detector(DetectorConfig(str(path))))
    (d,) = result_for(server)["detections"]
    assert d["bbox"] == pytest.approx([0, 0, 128, 64], abs=0.2)  # clipped to the frame, as Ultralytics does


# -- bad models: `netapp serve` says one line, exits 2, serves nothing ------------------------------------------------


def refused(*args: str) -> str:
    port = free_port()
    run = subprocess.run(
        serve_command(*args, "--port", str(port)),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1, run.stderr
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
    return lines[0]


def test_an_unknown_layout_is_refused_saying_what_was_seen(tmp_path):
    path = constant_model(tmp_path / "odd.onnx", {"output0": np.zeros((1, 5000, 7), np.float32)})
    line = refused("--model", str(path))
    assert "outputs output0 [1, 5000, 7] for input 64x64 match no known family" in line
    assert "YOLOX (1, A, 5+C)" in line and "RF-DETR" in line


def test_metadata_that_contradicts_the_outputs_is_refused(tmp_path):
    names = str({i: f"n{i}" for i in range(5)})
    path = yolov8_model(tmp_path / "liar.onnx", TINY_BOX, 0, metadata={"task": "detect", "names": names})
    line = refused("--model", str(path))
    assert "the model's metadata names 5 classes but its outputs (output [1, 7, 84]) hold 3 classes" in line


def test_a_truncated_file_is_refused(tmp_path, tiny_model_path):
    cut = tmp_path / "cut.onnx"
    cut.write_bytes(tiny_model_path.read_bytes()[:300])
    assert "cannot load ONNX model" in refused("--model", str(cut))


def test_a_device_that_is_absent_is_refused(tiny_model_path):
    import onnxruntime

    if "CUDAExecutionProvider" in onnxruntime.get_available_providers():
        pytest.skip("this onnxruntime offers CUDA")
    line = refused("--model", str(tiny_model_path), "--device", "cuda")
    assert "--device cuda: this onnxruntime offers only cpu" in line and "onnxruntime-gpu" in line


def test_thresholds_the_references_use_are_accepted(tiny_model_path):
    """--conf 0.0001 --iou 0.7 --max-detections 50 are taken; a threshold no model can use is refused."""
    assert "--conf 1.5 is not a score threshold" in refused("--model", str(tiny_model_path), "--conf", "1.5")
    from netapp.cli import build_parser

    args = build_parser().parse_args(
        ["serve", "--model", "m.onnx", "--conf", "0.0001", "--iou", "0.7", "--max-detections", "50"]
    )
    assert (args.conf, args.iou, args.max_detections) == (0.0001, 0.7, 50)
