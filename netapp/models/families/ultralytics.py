"""Ultralytics YOLOv8 / YOLO11 exports (NMS not in the graph): detect (1, 4+C, A), segment (+ prototypes
(1, 32, H/4, W/4)), pose (1, 4+C+K*D, A), oriented boxes (1, 4+C+1, A; angle in radians last) and classify (1, C).

Recognised by the metadata Ultralytics writes (task, names, kpt_shape), else by the shapes (A = the anchor count of
the input size); pose and obb need the metadata or --task, since their shapes look like a detector's."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netapp.models.card import ModelCard, Pixels
from netapp.models.decoding import best_class, xywh_to_xyxy
from netapp.models.families.base import Family, Recognition, Signature, contradiction, int_shape
from netapp.models.labels import COCO_CLASSES
from netapp.models.layouts import anchor_count
from netapp.models.tasks import Candidates
from netapp.results import COCO_KEYPOINTS

DEFAULT_KPT_SHAPE = (len(COCO_KEYPOINTS), 3)


def letterboxed(input_hw: tuple[int, int]) -> Pixels:
    return Pixels(input_hw, "letterbox", rgb=True, scale=1 / 255)


def prototypes(sig: Signature) -> int:
    """The mask coefficient count when the second output is a (1, M, H/4, W/4) prototype stack, else 0."""
    if len(sig.outputs) != 2:
        return 0
    shape = sig.outputs[1].shape
    if len(shape) == 4 and int_shape(shape) and shape[2] * 4 == sig.input_hw[0] and shape[3] * 4 == sig.input_hw[1]:
        return int(shape[1])
    return 0


class Ultralytics(Family):
    name = "ultralytics"
    shapes = "YOLOv8/YOLO11 (1, 4+C[+32|+K*3|+1], A) [+ prototypes (1, 32, H/4, W/4)], classify (1, C)"

    def recognise(self, sig: Signature) -> Recognition | None:
        meta = sig.metadata
        if meta.end2end or (meta.head or "").startswith("RTDETR"):
            return None  # the end-to-end and RT-DETR families read those
        task = sig.task or meta.task
        first = sig.outputs[0].shape
        why = f"Ultralytics metadata (task {meta.task}, {len(meta.names)} names)" if meta.ultralytics else ""
        if len(sig.outputs) == 1 and len(first) == 2 and int_shape(first) and task in (None, "classify"):
            classes = int(first[1])
            if sig.names and len(sig.names) != classes:
                raise contradiction(sig, "class scores", classes)
            size = sig.input_hw
            return Recognition(
                "classify",
                classes,
                Pixels(size, "crop", rgb=True, scale=1 / 255),
                why or f"one {list(first)} output: an image classifier",
            )
        anchors = anchor_count(sig.input_hw)
        if len(first) != 3 or not int_shape(first) or first[2] != anchors or first[1] <= 4:
            return None
        channels = int(first[1])
        masks = prototypes(sig)
        task = task or ("segment" if masks else "detect")
        kpt = meta.kpt_shape or DEFAULT_KPT_SHAPE if task == "pose" else None
        extra = {"detect": 0, "segment": masks, "pose": kpt[0] * kpt[1] if kpt else 0, "obb": 1}.get(task)
        if extra is None or (task == "segment" and not masks):
            return None
        classes = channels - 4 - extra
        if classes < 1:
            return None
        if sig.names and len(sig.names) != classes:
            raise contradiction(sig, f"classes for a {task} model", classes)
        if not why:
            why = f"output {list(first)}: 4 box values and {classes} class scores over {anchors} anchors"
            why += f", prototypes {list(sig.outputs[1].shape)}" if masks else ""
            why += f" ({task} as --task says)" if sig.task else ""
        return Recognition(
            task,
            classes,
            letterboxed(sig.input_hw),
            why,
            keypoints=kpt,
            mask_channels=masks,
            default_names=COCO_CLASSES if classes == len(COCO_CLASSES) else None,
        )

    def candidates(self, outputs: Sequence[np.ndarray], card: ModelCard, conf: float) -> Candidates:
        if card.task == "classify":
            return Candidates.classes(outputs[0].reshape(-1))
        pred = outputs[0]  # channels x anchors
        nc = card.num_classes
        keep, scores, class_ids = best_class(pred[4 : 4 + nc], conf)
        rows = pred[:, keep].T
        protos = outputs[1] if card.task == "segment" else None
        if card.task == "obb":
            boxes = np.concatenate((rows[:, :4], rows[:, -1:]), axis=1)  # cx, cy, w, h, angle
            return Candidates(boxes, scores, class_ids)
        extra = rows[:, 4 + nc :] if card.task in ("segment", "pose") else None
        return Candidates(xywh_to_xyxy(rows[:, :4]), scores, class_ids, extra=extra, protos=protos)


FAMILY = Ultralytics()
