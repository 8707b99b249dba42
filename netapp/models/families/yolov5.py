"""YOLOv5 exports: (1, 3A, 5+C) rows of centre, size (input pixels), objectness and class scores; the -seg
exports add 32 mask coefficients per row and a (1, 32, H/4, W/4) prototype output."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netapp.models.card import ModelCard
from netapp.models.decoding import xywh_to_xyxy
from netapp.models.families.base import Family, Recognition, Signature, contradiction, int_shape
from netapp.models.families.ultralytics import letterboxed, prototypes
from netapp.models.labels import COCO_CLASSES
from netapp.models.layouts import anchor_count
from netapp.models.tasks import Candidates


class Yolov5(Family):
    name = "yolov5"
    shapes = "YOLOv5 (1, 3A, 5+C[+32]) [+ prototypes]"

    def recognise(self, sig: Signature) -> Recognition | None:
        first = sig.outputs[0].shape
        anchors = 3 * anchor_count(sig.input_hw)
        if len(first) != 3 or not int_shape(first) or first[1] != anchors:
            return None
        masks = prototypes(sig)
        classes = int(first[2]) - 5 - masks
        if classes < 1 or sig.task not in (None, "segment" if masks else "detect"):
            return None
        if sig.names and len(sig.names) != classes:
            raise contradiction(sig, "classes", classes)
        return Recognition(
            "segment" if masks else "detect",
            classes,
            letterboxed(sig.input_hw),
            f"output {list(first)}: box, objectness and {classes} class scores"
            + (f" and {masks} mask coefficients" if masks else "")
            + f" per anchor (3 x {anchors // 3})",
            mask_channels=masks,
            default_names=COCO_CLASSES if classes == len(COCO_CLASSES) else None,
        )

    def candidates(self, outputs: Sequence[np.ndarray], card: ModelCard, conf: float) -> Candidates:
        pred = outputs[0]
        nc = card.num_classes
        rows = pred[pred[:, 4] >= conf]
        cls = rows[:, 5 : 5 + nc]
        class_ids = cls.argmax(axis=1)
        scores = (cls[np.arange(len(cls)), class_ids] * rows[:, 4]).astype(np.float32)
        keep = scores >= conf
        rows = rows[keep]
        extra = rows[:, 5 + nc :] if card.task == "segment" else None
        protos = outputs[1] if card.task == "segment" else None
        return Candidates(xywh_to_xyxy(rows[:, :4]), scores[keep], class_ids[keep], extra=extra, protos=protos)


FAMILY = Yolov5()
