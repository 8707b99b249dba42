"""The model processor: onnxruntime inference of any export the families recognise, one instance shared by all
robots. Reads the model (metadata, then output shapes, then flags), prepares each frame as its exporter does,
runs a batch, and decodes each frame's outputs into detections (masks, keypoints, oriented boxes) or
classifications, in the frame's own pixels."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from netapp.models.card import ModelCard
from netapp.models.families.base import Family
from netapp.models.memory import DEFAULT_MAX_MODEL_MEMORY_MB, first_run, gpu_limited, limit_memory
from netapp.models.preprocess import Placement, center_crop, letterbox, stretch
from netapp.models.profiles import profile_for
from netapp.models.providers import PROVIDERS, DeviceUnavailable, choose_device, preload
from netapp.models.reading import MAX_INPUT_PIXELS, open_session, read_model
from netapp.models.tasks import DecodeOptions, finish
from netapp.sdk.processor import Processor

log = logging.getLogger(__name__)


@dataclass
class DetectorConfig:
    model_path: str
    labels_path: str | None = None
    conf: float = 0.3
    iou: float = 0.45
    max_detections: int = 300
    input_size: int = 640  # used only when the model's input size is dynamic and its metadata names none
    device: str = "auto"  # auto | cpu | cuda | tensorrt | openvino (netapp/models/providers.py)
    trt_cache: str | None = None  # TensorRT's engine cache (default ~/.cache/netapp/trt)
    fp16: bool = False  # TensorRT and OpenVINO in half precision
    threads: int = 0  # onnxruntime intra-op threads; 0 lets it use every core
    spin_wait: bool = False  # intra-op threads spin between operators instead of sleeping
    task: str | None = None  # --task: overrides the metadata's
    layout: str | None = None  # --layout: the one family to read the model as
    mask_format: str = "polygons"  # or "rle"
    top_k: int = 5  # classifications per frame
    max_pixels: int | None = MAX_INPUT_PIXELS  # the largest input the model may ask for (`--max-pixels`)
    max_model_memory_mb: int = DEFAULT_MAX_MODEL_MEMORY_MB  # its CPU arena at most (`--max-model-memory`; 0: unbounded)


@dataclass
class Prepared:
    feeds: dict[str, np.ndarray]
    placement: Placement


class Detector(Processor):
    """Loads the ONNX model, recognises its family and task, prepares frames, infers, decodes."""

    def __init__(self, config: DetectorConfig) -> None:
        self.config = config
        self.name = Path(config.model_path).stem
        self.session = None
        self.family: Family | None = None
        self.card: ModelCard | None = None
        self.input_name = ""
        self.input_hw = (config.input_size, config.input_size)
        self.provider = ""
        self.device_why = ""
        self.accuracy_profile: str | None = None
        self.dropped: Counter[str] = Counter()  # detections decoding left out, by reason: the netapp counts them
        self.options = DecodeOptions(config.conf, config.iou, config.max_detections, config.mask_format, config.top_k)

    @property
    def class_names(self) -> list[str]:
        return list(self.card.classes) if self.card else []

    def load(self) -> None:
        if self.session is not None:
            return  # already loaded (the CLI loads early to fail fast)
        import onnxruntime as ort

        config = self.config
        gpu_libs = preload()  # NVIDIA's libraries from their wheels, before a CUDA or TensorRT session needs them
        if gpu_libs.cuda_build:
            log.info("%s", gpu_libs.describe())
        choice = choose_device(config.device, ort.get_available_providers(), config.trt_cache, config.fp16)
        if choice.device == "tensorrt":
            Path(dict(choice.providers[0][1])["trt_engine_cache_path"]).mkdir(parents=True, exist_ok=True)
        options = ort.SessionOptions()
        options.intra_op_num_threads = config.threads
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        # Spinning workers keep a core busy between operators; beside an event loop, or on a shared machine, that
        # core is the one the loop needs (measured: docs/benchmarks.md#what-the-knobs-do).
        options.add_session_config_entry("session.intra_op.allow_spinning", "1" if config.spin_wait else "0")
        budget_mb = limit_memory(options, config.max_model_memory_mb)
        providers = gpu_limited(choice.providers, config.max_model_memory_mb)
        session = open_session(config.model_path, providers, options)
        self.provider = session.get_providers()[0]
        if config.device != "auto" and self.provider != PROVIDERS[choice.device]:
            raise DeviceUnavailable(
                f"--device {config.device}: onnxruntime could not start {PROVIDERS[choice.device]} and fell back to "
                f"{self.provider} (its log above says why): fix the driver or libraries, or use --device auto"
            )
        self.device_why = choice.why
        self.family, self.card = read_model(
            config.model_path,
            task=config.task,
            layout=config.layout,
            labels=config.labels_path,
            session=session,
            max_pixels=config.max_pixels,
        )
        self.session = session
        image = next(t for t in self.card.inputs if len(t.shape) == 4)
        self.input_name = image.name
        self.input_hw = self.card.pixels.size_hw
        self.max_batch = max(1, image.shape[0]) if isinstance(image.shape[0], int) else 8
        self.accuracy_profile = profile_for(config.model_path)
        warm_up = [self.prepare(np.zeros((*self.input_hw, 3), np.uint8), {})]
        first_run(lambda: self.process(warm_up), config.model_path, budget_mb)  # one line if it fails or is too big
        log.info("model %s: %s", config.model_path, self.card.line())
        log.info("model %s runs on %s (%s)", self.name, self.provider, self.device_why)
        if self.accuracy_profile is None:
            log.info(
                "no accuracy profile was made for %s: robots that adapt use their conservative defaults", self.name
            )

    @property
    def input_size(self) -> tuple[int, int] | None:  # type: ignore[override]
        """(width, height) a robot's frame is fitted into: the model's input; None for a classifier, whose centre
        crop of the shorter side wants the frame as it is."""
        if self.card is not None and self.card.pixels.resize == "crop":
            return None
        return self.input_hw[1], self.input_hw[0]

    def prepare(self, image: np.ndarray, args: Mapping[str, Any]) -> Prepared:
        assert self.card is not None and self.family is not None, "load() first"
        px = self.card.pixels
        if px.resize == "stretch":
            blob, placement = stretch(image, px.size_hw, rgb=px.rgb, scale=px.scale, mean=px.mean, std=px.std)
        elif px.resize == "crop":
            blob = center_crop(image, px.size_hw, rgb=px.rgb, scale=px.scale)
            placement = Placement(1.0, 1.0, 0.0, 0.0, image.shape[1], image.shape[0])  # no boxes to map back
        else:
            blob, placement = letterbox(image, px.size_hw, center=px.resize == "letterbox", rgb=px.rgb, scale=px.scale)
        return Prepared({self.input_name: blob, **self.family.extra_inputs(self.card, placement)}, placement)

    def process(self, batch: Sequence[Prepared]) -> list[dict[str, Any]]:
        assert self.session is not None and self.card is not None and self.family is not None, "load() first"
        if len(batch) == 1:
            feeds = batch[0].feeds
        else:
            feeds = {name: np.concatenate([p.feeds[name] for p in batch]) for name in batch[0].feeds}
        outputs = self.session.run(None, feeds)
        results = []
        for i, prepared in enumerate(batch):
            found = self.family.candidates([o[i] for o in outputs], self.card, self.config.conf)
            results.append(finish(found, self.card, prepared.placement, self.options, self.dropped))
        return results

    def detect(self, image: np.ndarray) -> list[dict[str, Any]]:
        """Detections for one BGR image (the in-process path, no framework)."""
        return self.process([self.prepare(image, {})])[0]["detections"]

    def describe(self) -> dict[str, Any]:
        card = self.card
        return {
            "name": self.name,
            "platform": "onnxruntime",
            "provider": self.provider,
            "layout": card.family if card else None,
            "family": card.family if card else None,
            "task": card.task if card else None,
            "inputs": [{"name": self.input_name, "datatype": "FP32", "shape": [1, 3, *self.input_hw]}],
            "classes": len(card.classes) if card else 0,
        }
