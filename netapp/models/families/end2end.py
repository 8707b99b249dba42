"""End-to-end exports without NMS (YOLOv10, YOLO26; Ultralytics `end2end` True): (1, N, 6) rows of x1, y1, x2, y2
(input pixels), score, class, the top N in descending score; -seg rows add mask coefficients (and a prototype
output), -pose rows keypoints, -obb rows carry cx, cy, w, h, score, class, angle. No NMS: rows over the threshold."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netapp.models.card import ModelCard
from netapp.models.families.base import Family, Recognition, Signature, int_shape
from netapp.models.families.ultralytics import DEFAULT_KPT_SHAPE, letterboxed, prototypes
from netapp.models.labels import COCO_CLASSES
from netapp.models.layouts import anchor_count
from netapp.models.tasks import Candidates

MAX_ROWS = 1000  # more rows than any end-to-end head keeps: a larger (1, N, 6) is some other layout


class EndToEnd(Family):
    name = "end2end"
    shapes = "YOLOv10/YOLO26 end-to-end (1, N, 6[+extra])"

    def recognise(self, sig: Signature) -> Recognition | None:
        meta = sig.metadata
        first = sig.outputs[0].shape
        anchors = anchor_count(sig.input_hw)
        if len(first) != 3 or not int_shape(first) or first[1] > MAX_ROWS or first[1] in (anchors, 3 * anchors):
            return None
        if (meta.head or "").startswith("RTDETR") or (meta.ultralytics and not meta.end2end):
            return None
        task = sig.task or meta.task or "detect"
        masks = prototypes(sig)
        if task == "segment" and not masks:
            return None
        kpt = (meta.kpt_shape or DEFAULT_KPT_SHAPE) if task == "pose" else None
        extra = {"detect": 0, "segment": masks, "pose": kpt[0] * kpt[1] if kpt else 0, "obb": 1}.get(task)
        if extra is None or first[2] != 6 + extra:
            return None
        classes = len(sig.names) if sig.names else len(COCO_CLASSES)  # the class is a column: the count is not seen
        why = (
            f"Ultralytics metadata end2end True (task {meta.task})"
            if meta.end2end
            else f"output {list(first)}: rows of box, score, class{' + extra' if extra else ''}"
        )
        return Recognition(
            task,
            classes,
            letterboxed(sig.input_hw),
            why + ", no NMS",
            keypoints=kpt,
            mask_channels=masks,
            default_names=COCO_CLASSES,
        )

    def candidates(self, outputs: Sequence[np.ndarray], card: ModelCard, conf: float) -> Candidates:
        rows = outputs[0]
        rows = rows[rows[:, 4] > conf]
        # a class past the names (a lying export) is not a class: drop its rows
        class_ids = rows[:, 5].astype(np.int64)
        valid = (class_ids >= 0) & (class_ids < card.num_classes)
        rows, class_ids = rows[valid], class_ids[valid]
        scores = rows[:, 4].astype(np.float32)
        if card.task == "obb":
            boxes = np.concatenate((rows[:, :4], rows[:, 6:7]), axis=1)
            return Candidates(boxes, scores, class_ids, nms=False)
        extra = rows[:, 6:] if card.task in ("segment", "pose") else None
        protos = outputs[1] if card.task == "segment" else None
        return Candidates(rows[:, :4], scores, class_ids, extra=extra, protos=protos, nms=False)


FAMILY = EndToEnd()
