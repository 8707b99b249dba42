"""Reading a model: Ultralytics' metadata (Python reprs), the providers `--device` picks, the card `netapp model
inspect` prints, and the exact COCO RLE of a mask cut to its box."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from netapp.models.decoding import region_rle
from netapp.models.metadata import read_metadata
from netapp.models.providers import DeviceUnavailable, choose_device
from netapp.results import mask_to_rle
from tests.support.onnx_models import constant_model, yolov8_pose_model

CPU, CUDA, TRT, OV = (
    "CPUExecutionProvider",
    "CUDAExecutionProvider",
    "TensorrtExecutionProvider",
    "OpenVINOExecutionProvider",
)


def test_ultralytics_metadata_is_read_as_python_reprs():
    meta = read_metadata(
        {
            "task": "pose",
            "names": "{0: 'person', 1: 'robot'}",
            "imgsz": "[480, 640]",
            "stride": "32",
            "kpt_shape": "[17, 3]",
            "end2end": "False",
            "head": "Pose",
        }
    )
    assert (meta.task, meta.names, meta.imgsz, meta.stride) == ("pose", ("person", "robot"), (480, 640), 32)
    assert (meta.kpt_shape, meta.end2end, meta.head, meta.ultralytics) == ((17, 3), False, "Pose", True)
    assert read_metadata({"end2end": "True"}).end2end is True
    hostile = read_metadata({"names": "{'a': 1}", "imgsz": "__import__('os')", "kpt_shape": "[" * 200, "task": "x"})
    assert (hostile.names, hostile.imgsz, hostile.kpt_shape, hostile.task) == (None, None, None, None)


def test_auto_takes_the_best_provider_present_and_says_why():
    assert choose_device("auto", [CPU]).providers == [CPU]
    best = choose_device("auto", [CPU, CUDA, TRT], trt_cache="/tmp/trt", fp16=True)
    assert best.device == "tensorrt" and "tensorrt, the best of those onnxruntime offers" in best.why
    name, options = best.providers[0]
    assert name == TRT and options["trt_fp16_enable"] is True and options["trt_engine_cache_path"] == "/tmp/trt"
    assert best.providers[1:] == [CUDA, CPU]  # what TensorRT cannot run falls to CUDA, then the CPU
    assert choose_device("auto", [CPU, OV]).device == "openvino"
    assert choose_device("cuda", [CPU, CUDA, TRT]).providers == [CUDA, CPU]
    assert choose_device("cpu", [CPU, CUDA]).providers == [CPU]


def test_a_device_that_is_absent_is_one_line_saying_what_is_there():
    with pytest.raises(DeviceUnavailable) as caught:
        choose_device("tensorrt", [CPU, CUDA])
    message = str(caught.value)
    assert "\n" not in message and "offers only cuda, cpu" in message and "--device auto" in message


def test_region_rle_is_cocos_rle_of_the_whole_frame():
    rng = np.random.default_rng(1)
    for _ in range(200):
        height, width = (int(v) for v in rng.integers(1, 40, 2))
        h, w = int(rng.integers(1, height + 1)), int(rng.integers(1, width + 1))
        y0, x0 = int(rng.integers(0, height - h + 1)), int(rng.integers(0, width - w + 1))
        mask = rng.random((h, w)) < rng.random()
        frame = np.zeros((height, width), bool)
        frame[y0 : y0 + h, x0 : x0 + w] = mask
        assert region_rle(mask, x0, y0, height, width) == mask_to_rle(frame)


def inspect(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "netapp", "model", "inspect", *args], capture_output=True, text=True, timeout=60
    )


def test_netapp_model_inspect_prints_the_card(tmp_path):
    path = yolov8_pose_model(tmp_path / "pose.onnx", (8.0, 16.0, 40.0, 48.0))
    text = inspect(str(path))
    assert text.returncode == 0, text.stderr
    assert "task       pose" in text.stdout and "keypoints  17 x 3" in text.stdout
    assert "why        Ultralytics metadata (task pose, 1 names)" in text.stdout
    card = json.loads(inspect(str(path), "--json").stdout)
    assert (card["family"], card["task"], card["classes"], card["keypoints"]) == (
        "ultralytics",
        "pose",
        ["person"],
        [17, 3],
    )
    assert card["pixels"] == {
        "size_hw": [64, 64],
        "resize": "letterbox",
        "rgb": True,
        "scale": 1 / 255,
        "mean": None,
        "std": None,
    }
    assert len(card["skeleton"]) == 19 and card["keypoint_names"][0] == "nose"


def test_netapp_model_inspect_refuses_in_one_line(tmp_path):
    odd = constant_model(tmp_path / "odd.onnx", {"output0": np.zeros((1, 5000, 7), np.float32)})
    out = inspect(str(odd))
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and "match no known family" in out.stderr
