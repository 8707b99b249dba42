"""Ultralytics RT-DETR exports (metadata `head` RTDETRDecoder; its `end2end` says False): (1, Q, 4+C), Q queries
(300) of normalised cx, cy, w, h and sigmoided class scores; the frame is stretched to the input, RGB 0-1; no NMS."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netapp.models.card import ModelCard, Pixels
from netapp.models.decoding import xywh_to_xyxy
from netapp.models.families.base import Family, Recognition, Signature, contradiction, int_shape
from netapp.models.families.end2end import MAX_ROWS
from netapp.models.labels import COCO_CLASSES
from netapp.models.layouts import anchor_count
from netapp.models.tasks import Candidates


class RtDetr(Family):
    name = "rtdetr"
    shapes = "RT-DETR (1, Q, 4+C) normalised cxcywh"

    def recognise(self, sig: Signature) -> Recognition | None:
        meta = sig.metadata
        first = sig.outputs[0].shape
        by_head = (meta.head or "").startswith("RTDETR")
        if len(sig.outputs) != 1 or len(first) != 3 or not int_shape(first) or sig.task not in (None, "detect"):
            return None
        anchors = anchor_count(sig.input_hw)
        if not by_head and (meta.ultralytics or first[1] > MAX_ROWS or first[1] in (anchors, 3 * anchors)):
            return None
        if not by_head and first[2] == 6:
            return None  # (1, N, 6) rows are the end-to-end family's
        classes = int(first[2]) - 4
        if classes < 1:
            return None
        if sig.names and len(sig.names) != classes:
            raise contradiction(sig, "class scores", classes)
        why = "Ultralytics metadata head RTDETRDecoder" if by_head else f"output {list(first)}: DETR queries"
        return Recognition(
            "detect",
            classes,
            Pixels(sig.input_hw, "stretch", rgb=True, scale=1 / 255),
            f"{why} of normalised cxcywh and {classes} class scores, stretched input, no NMS",
            default_names=COCO_CLASSES if classes == len(COCO_CLASSES) else None,
        )

    def candidates(self, outputs: Sequence[np.ndarray], card: ModelCard, conf: float) -> Candidates:
        pred = outputs[0]
        cls = pred[:, 4:]
        class_ids = cls.argmax(axis=1)
        scores = cls[np.arange(len(cls)), class_ids].astype(np.float32)
        keep = np.flatnonzero(scores > conf)
        h, w = card.pixels.size_hw
        boxes = xywh_to_xyxy(pred[keep, :4] * np.float32([w, h, w, h]))
        return Candidates(boxes, scores[keep], class_ids[keep], nms=False)


FAMILY = RtDetr()
