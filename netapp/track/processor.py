"""The object-tracking netapp: the detector, batched across robots, then each robot's own tracker."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from netapp.detections import Detections
from netapp.models.detector import Detector, DetectorConfig
from netapp.sdk.processor import StatefulProcessor
from netapp.track.tracker import Tracker, TrackerConfig


class TrackingDetector(StatefulProcessor):
    """Detections with a `track_id` each: the same object keeps its id from frame to frame (None until its track is
    confirmed). A session's state is its tracker; it moves between netapps as JSON (about 0.35 KB per track)."""

    def __init__(self, detector: DetectorConfig | Detector, tracker: TrackerConfig | None = None) -> None:
        self.detector = detector if isinstance(detector, Detector) else Detector(detector)
        self.tracker_config = tracker or TrackerConfig()
        self.name = self.detector.name

    @property
    def max_batch(self) -> int:  # the model decides, once loaded
        return self.detector.max_batch

    @property
    def input_size(self) -> tuple[int, int]:  # type: ignore[override]
        return self.detector.input_size

    @property
    def accuracy_profile(self) -> str | None:  # type: ignore[override]
        return self.detector.accuracy_profile

    def load(self) -> None:
        self.detector.load()
        Tracker(self.tracker_config)  # imports the tracking library now, not on the first robot's INIT

    def prepare(self, image: np.ndarray, args: Mapping[str, Any]) -> Any:
        return self.detector.prepare(image, args)

    def process(self, batch: Sequence[Any]) -> list[dict[str, Any]]:
        return self.detector.process(batch)

    def new_state(self, args: Mapping[str, Any]) -> Tracker:
        return Tracker(self.tracker_config)

    def update(self, state: Tracker, result: dict[str, Any], timestamp: int) -> dict[str, Any]:
        return state.track(Detections.from_wire(result, strict=False), timestamp / 1e9).to_wire()

    def state_to_json(self, state: Tracker) -> dict[str, Any]:
        return state.to_json()

    def state_from_json(self, data: Any) -> Tracker:
        tracker = Tracker(self.tracker_config)
        tracker.load_json(data)
        return tracker

    def describe(self) -> dict[str, Any]:
        return {**self.detector.describe(), "tracker": "bytetrack"}
