"""RF-DETR exports (Roboflow's `export()`): input `input` (1, 3, R, R), outputs `dets` (1, Q, 4) normalised
cx, cy, w, h and `labels` (1, Q, C) class logits; ImageNet-normalised RGB, stretched to R x R. The top Q
(query, class) pairs by sigmoid score are the detections, as its own post-processing picks them; no NMS."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netapp.models.card import ModelCard, Pixels
from netapp.models.decoding import xywh_to_xyxy
from netapp.models.families.base import Family, Recognition, Signature, contradiction, int_shape
from netapp.models.labels import COCO_CLASSES, coco91_names
from netapp.models.tasks import Candidates

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
NUM_SELECT = 300  # (query, class) pairs its post-processing keeps


class RfDetr(Family):
    name = "rfdetr"
    shapes = "RF-DETR dets (1, Q, 4) + labels (1, Q, C)"

    def recognise(self, sig: Signature) -> Recognition | None:
        dets, labels = sig.output("dets"), sig.output("labels")
        if dets is None or labels is None or len(dets.shape) != 3 or len(labels.shape) != 3:
            return None
        if (
            not (int_shape(dets.shape) and int_shape(labels.shape))
            or dets.shape[2] != 4
            or sig.task
            not in (
                None,
                "detect",
            )
        ):
            return None
        classes = int(labels.shape[2])
        if sig.names and len(sig.names) != classes:
            raise contradiction(sig, "class logits", classes)
        default = coco91_names() if classes == 91 else COCO_CLASSES if classes == len(COCO_CLASSES) else None
        return Recognition(
            "detect",
            classes,
            Pixels(sig.input_hw, "stretch", rgb=True, scale=1 / 255, mean=IMAGENET_MEAN, std=IMAGENET_STD),
            f"outputs dets {list(dets.shape)} and labels {list(labels.shape)}: RF-DETR queries, no NMS",
            default_names=default,
        )

    def candidates(self, outputs: Sequence[np.ndarray], card: ModelCard, conf: float) -> Candidates:
        names = [t.name for t in card.outputs]
        dets, logits = outputs[names.index("dets")], outputs[names.index("labels")]
        probs = 1 / (1 + np.exp(-logits.astype(np.float32)))
        flat = probs.reshape(-1)
        count = min(NUM_SELECT, flat.size)
        top = np.argpartition(-flat, count - 1)[:count]
        top = top[flat[top] > conf]
        queries, class_ids = np.divmod(top, probs.shape[1])
        h, w = card.pixels.size_hw
        boxes = xywh_to_xyxy(dets[queries] * np.float32([w, h, w, h]))
        return Candidates(boxes, flat[top].astype(np.float32), class_ids, nms=False)


FAMILY = RfDetr()
