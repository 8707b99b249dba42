"""Processors for tests of queueing, deadlines and back-pressure: they hold or slow every batch on purpose."""

from __future__ import annotations

import threading
import time

from netapp.sdk import Processor


class GatedProcessor(Processor):
    """A processor that holds every batch until the test opens the gate: makes queueing deterministic."""

    name = "gated"
    max_batch = 1

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.entered = threading.Semaphore(0)  # released once per batch that reached process()
        self.calls = 0

    def load(self) -> None:
        pass

    def prepare(self, image, args):
        return image.shape

    def process(self, batch):
        self.calls += 1
        self.entered.release()
        assert self.gate.wait(30), "the test never opened the gate"
        return [{"shape": list(shape)} for shape in batch]

    def describe(self):
        return {"name": self.name}


class SlowProcessor(GatedProcessor):
    """Takes `seconds` per batch, like a model on a busy CPU; counts the batches it was given."""

    name = "slow"

    def __init__(self, seconds: float) -> None:
        super().__init__()
        self.seconds = seconds

    def process(self, batch):
        self.calls += 1
        time.sleep(self.seconds)  # the cost of inference, not synchronisation
        return [{"shape": list(shape)} for shape in batch]


class ShapeRecorder(Processor):
    """Declares `input_size` and records the (width, height) of every frame it gets; finds one box covering each
    whole frame, so a robot's scale-back is visible."""

    name = "shapes"

    def __init__(self, input_size: tuple[int, int] | None = (416, 416)) -> None:
        self.input_size = input_size
        self.sizes: list[tuple[int, int]] = []

    def prepare(self, image, args):
        self.sizes.append((image.shape[1], image.shape[0]))
        return image.shape

    def process(self, batch):
        return [{"detections": [{"bbox": [0, 0, w, h], "score": 1.0, "class": 0}]} for h, w, _ in batch]


class LargeResults(Processor):
    """Answers every frame at once with a result of `size` bytes, to fill a robot's socket buffers quickly."""

    name = "large-results"

    def __init__(self, size: int = 50_000) -> None:
        self.blob = "x" * size

    def prepare(self, image, args):
        return None

    def process(self, batch):
        return [{"detections": [], "blob": self.blob} for _ in batch]
