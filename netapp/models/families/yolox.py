"""YOLOX exports without decode-in-inference: (1, A, 5+C) rows of grid offsets, log sizes, objectness and class
scores (sigmoided), A = the anchor count of the input size; BGR 0-255, padded at the bottom-right."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netapp.models.card import ModelCard, Pixels
from netapp.models.decoding import xywh_to_xyxy
from netapp.models.families.base import Family, Recognition, Signature, contradiction, int_shape
from netapp.models.labels import COCO_CLASSES
from netapp.models.layouts import anchor_count, grid_points
from netapp.models.tasks import Candidates


class Yolox(Family):
    name = "yolox"
    shapes = "YOLOX (1, A, 5+C)"

    def recognise(self, sig: Signature) -> Recognition | None:
        first = sig.outputs[0].shape
        anchors = anchor_count(sig.input_hw)
        if sig.metadata.ultralytics or len(sig.outputs) != 1 or len(first) != 3 or not int_shape(first):
            return None
        if first[1] != anchors or first[2] <= 5 or sig.task not in (None, "detect"):
            return None
        classes = int(first[2]) - 5
        if sig.names and len(sig.names) != classes:
            raise contradiction(sig, "classes", classes)
        return Recognition(
            "detect",
            classes,
            Pixels(sig.input_hw, "letterbox-corner", rgb=False, scale=1.0),
            f"output {list(first)}: one row of box, objectness and {classes} class scores per anchor ({anchors})",
            default_names=COCO_CLASSES if classes == len(COCO_CLASSES) else None,
            extras={"grid": grid_points(sig.input_hw)},
        )

    def candidates(self, outputs: Sequence[np.ndarray], card: ModelCard, conf: float) -> Candidates:
        pred = outputs[0].reshape(-1, 5 + card.num_classes)
        cls = pred[:, 5:]
        class_ids = cls.argmax(axis=1)
        scores = cls[np.arange(len(cls)), class_ids] * pred[:, 4]
        keep = np.flatnonzero(scores >= conf)
        grids, strides = card.extras["grid"]
        p, g, s = pred[keep], grids[keep], strides[keep]
        xy = (p[:, :2] + g) * s
        wh = np.exp(np.minimum(p[:, 2:4], 20.0)) * s  # clamp: a wild logit must not overflow to inf
        boxes = xywh_to_xyxy(np.concatenate((xy, wh), axis=1))
        return Candidates(boxes, scores[keep].astype(np.float32), class_ids[keep])


FAMILY = Yolox()
