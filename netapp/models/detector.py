"""The detector processor: onnxruntime inference of a YOLO-family export, one instance shared by all robots."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from netapp.models.labels import COCO_CLASSES, load_labels, names_from_metadata
from netapp.models.layouts import Layout, identify_layout
from netapp.models.preprocess import Letterbox, letterbox, unletterbox
from netapp.sdk.processor import Processor

log = logging.getLogger(__name__)


@dataclass
class DetectorConfig:
    model_path: str
    labels_path: str | None = None
    conf: float = 0.3
    iou: float = 0.45
    max_detections: int = 300
    input_size: int = 640  # used only when the model's input size is dynamic
    providers: tuple[str, ...] | None = None  # None: CUDA when onnxruntime offers it, else CPU
    threads: int = 0  # onnxruntime intra-op threads; 0 lets it use every core
    spin_wait: bool = False  # intra-op threads spin between operators instead of sleeping


@dataclass
class Prepared:
    blob: np.ndarray
    placement: Letterbox


class Detector(Processor):
    """Loads the ONNX model, recognises its layout, letterboxes, infers, decodes, runs NMS."""

    # YOLOX-Nano's profile stands for every YOLOX detector: scaling and JPEG's losses hurt them much alike.
    accuracy_profile = "yolox_nano"

    def __init__(self, config: DetectorConfig) -> None:
        self.config = config
        self.name = Path(config.model_path).stem
        self.session = None
        self.layout: Layout | None = None
        self.class_names: list[str] = []
        self.input_name = ""
        self.input_hw = (config.input_size, config.input_size)
        self.provider = ""

    def load(self) -> None:
        if self.session is not None:
            return  # already loaded (the CLI loads early to fail fast)
        import onnxruntime as ort

        available = ort.get_available_providers()
        wanted = self.config.providers or tuple(
            p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in available
        )
        options = ort.SessionOptions()
        options.intra_op_num_threads = self.config.threads
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        # Spinning workers keep a core busy between operators; beside an event loop, or on a shared machine, that
        # core is the one the loop needs (measured: docs/benchmarks.md#what-the-knobs-do).
        options.add_session_config_entry("session.intra_op.allow_spinning", "1" if self.config.spin_wait else "0")
        try:
            self.session = ort.InferenceSession(self.config.model_path, sess_options=options, providers=list(wanted))
        except Exception as exc:  # onnxruntime raises its own exception types for unreadable models
            raise ValueError(f"cannot load ONNX model {self.config.model_path}: {exc}") from exc
        self.provider = self.session.get_providers()[0]
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        if len(inputs) != 1 or len(inputs[0].shape) != 4:
            raise ValueError(f"{self.config.model_path} is not an image detector: expected one NCHW input")
        shape = inputs[0].shape
        self.input_name = inputs[0].name
        if isinstance(shape[2], int) and isinstance(shape[3], int):
            self.input_hw = (shape[2], shape[3])
        self.max_batch = 8 if not isinstance(shape[0], int) else max(1, shape[0])
        out_shape = tuple(outputs[0].shape)
        if not all(isinstance(d, int) for d in out_shape[1:]):
            out_shape = self.session.run(None, {self.input_name: self._zeros()})[0].shape  # dynamic: probe once
        self.layout = identify_layout(out_shape, self.input_hw)
        self.class_names = self._class_names(self.session.get_modelmeta().custom_metadata_map)
        self.process([self.prepare(np.zeros((self.input_hw[0], self.input_hw[1], 3), np.uint8), {})])  # warm-up
        log.info(
            "model %s: layout %s, %d classes, input %dx%d, provider %s",
            self.config.model_path,
            self.layout.name,
            self.layout.num_classes,
            self.input_hw[1],
            self.input_hw[0],
            self.provider,
        )

    @property
    def input_size(self) -> tuple[int, int]:  # type: ignore[override]
        """(width, height) of the model's input: its fixed shape, or `DetectorConfig.input_size` when dynamic."""
        return self.input_hw[1], self.input_hw[0]

    def _zeros(self) -> np.ndarray:
        return np.zeros((1, 3, *self.input_hw), np.float32)

    def _class_names(self, metadata: Mapping[str, str]) -> list[str]:
        assert self.layout is not None
        n = self.layout.num_classes
        if self.config.labels_path:
            names = load_labels(self.config.labels_path)
        else:
            names = names_from_metadata(dict(metadata)) or (list(COCO_CLASSES) if n == len(COCO_CLASSES) else [])
        if not names:
            return [f"class_{i}" for i in range(n)]
        if len(names) != n:
            raise ValueError(f"the model has {n} classes but {len(names)} class names were given")
        return names

    def prepare(self, image: np.ndarray, args: Mapping[str, Any]) -> Prepared:
        assert self.layout is not None, "load() first"
        blob, placement = letterbox(
            image, self.input_hw, center=self.layout.center_pad, rgb=self.layout.rgb, scale=self.layout.scale
        )
        return Prepared(blob, placement)

    def process(self, batch: Sequence[Prepared]) -> list[dict[str, Any]]:
        assert self.session is not None and self.layout is not None, "load() first"
        if len(batch) == 1:
            outputs = self.session.run(None, {self.input_name: batch[0].blob})[0]
        else:
            outputs = self.session.run(None, {self.input_name: np.concatenate([p.blob for p in batch])})[0]
        return [{"detections": self._detections(out, p.placement)} for out, p in zip(outputs, batch, strict=True)]

    def detect(self, image: np.ndarray) -> list[dict[str, Any]]:
        """Detections for one BGR image (the in-process path, no framework)."""
        return self.process([self.prepare(image, {})])[0]["detections"]

    def _detections(self, output: np.ndarray, placement: Letterbox) -> list[dict[str, Any]]:
        assert self.layout is not None
        boxes, scores, class_ids = self.layout.decode(output, self.input_hw, self.config.conf)
        if len(scores) == 0:
            return []
        xywh = np.concatenate((boxes[:, :2], boxes[:, 2:] - boxes[:, :2]), axis=1)
        keep = cv2.dnn.NMSBoxesBatched(
            xywh.tolist(), scores.tolist(), class_ids.tolist(), self.config.conf, self.config.iou
        )
        keep = np.asarray(keep, dtype=np.int64).reshape(-1)[: self.config.max_detections]
        if len(keep) == 0:
            return []
        original = unletterbox(boxes[keep], placement)
        return [
            {
                "bbox": [round(float(v), 1) for v in box],
                "score": round(float(score), 4),
                "class": int(cid),
                "class_name": self.class_names[int(cid)],
            }
            for box, score, cid in zip(original, scores[keep], class_ids[keep], strict=True)
        ]

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "platform": "onnxruntime",
            "provider": self.provider,
            "layout": self.layout.name if self.layout else None,
            "inputs": [{"name": self.input_name, "datatype": "FP32", "shape": [1, 3, *self.input_hw]}],
            "classes": len(self.class_names),
        }
