"""The real Ultralytics exports in ../shared/models/exports and the predictions Ultralytics made from them (read
../shared/models/exports/README.md): where they are, and a plain re-statement of how Ultralytics turns a
segmentation output into a frame's mask, to compare the netapp's masks with."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.support.paths import SHARED

EXPORTS = Path(os.environ.get("NETAPP_TEST_EXPORTS", SHARED / "models" / "exports"))
# the predict() arguments every reference was made with
REFERENCE_ARGS = {"conf": 0.0001, "iou": 0.7, "max_detections": 50}
MODELS = ("yolo11n", "yolo11n-seg", "yolo11n-pose", "yolo11n-obb", "yolo11n-cls", "yolo26n")
IMAGES = ("dog", "ped100")


def export_path(model: str) -> Path:
    path = EXPORTS / f"{model}.onnx"
    if not path.exists():
        pytest.skip(f"{path} is absent: the shared exports (../shared/models/exports, or NETAPP_TEST_EXPORTS) hold it")
    return path


def reference(model: str, image: str) -> dict:
    path = EXPORTS / "reference" / f"{model}__{image}.json"
    if not path.exists():
        pytest.skip(f"{path} is absent: the shared exports' reference predictions hold it")
    return json.loads(path.read_text())


def robot_frame(media_dir: Path, image: str) -> tuple[bytes, np.ndarray]:
    """The JPEG's bytes, as a robot sends them to /send_image, and the frame the netapp decodes from them."""
    data = (media_dir / f"{image}.jpg").read_bytes()
    return data, cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def ultralytics_mask(
    coefficients: np.ndarray, protos: np.ndarray, box: np.ndarray, input_hw: tuple[int, int], placement
) -> np.ndarray:
    """Ultralytics' way, written plainly: upsample the whole 160x160 logits to the input, keep > 0 inside the box
    (input pixels), cut the letterbox's padding away and resize to the frame, keep > 0.5 (process_mask, then
    scale_masks)."""
    channels, ph, pw = protos.shape
    in_h, in_w = input_hw
    logits = (coefficients @ protos.reshape(channels, -1)).reshape(ph, pw)
    up = cv2.resize(logits, (in_w, in_h), interpolation=cv2.INTER_LINEAR)
    cols, rows = np.arange(in_w)[None, :], np.arange(in_h)[:, None]
    mask = (up > 0) & (cols >= box[0]) & (cols < box[2]) & (rows >= box[1]) & (rows < box[3])
    top, left = int(placement.pad_y), int(placement.pad_x)
    inner = mask[top : in_h - top, left : in_w - left].astype(np.float32)
    return cv2.resize(inner, (placement.width, placement.height), interpolation=cv2.INTER_LINEAR) > 0.5
