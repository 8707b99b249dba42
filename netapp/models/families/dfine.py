"""D-FINE exports (its tools/deployment/export_onnx.py; RT-DETRv2's too): inputs `images` (N, 3, 640, 640) and
`orig_target_sizes` (N, 2: width, height), outputs `labels` (N, Q), `boxes` (N, Q, 4: x1, y1, x2, y2 in the target
size's pixels) and `scores` (N, Q); RGB 0-1, stretched. The netapp gives the input's own size as the target and
maps the boxes back itself, like every other family; no NMS."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from netapp.models.card import ModelCard, Pixels
from netapp.models.families.base import Family, Recognition, Signature
from netapp.models.labels import COCO_CLASSES
from netapp.models.preprocess import Placement
from netapp.models.tasks import Candidates

TARGET_SIZES = "orig_target_sizes"


class DFine(Family):
    name = "dfine"
    shapes = "D-FINE images + orig_target_sizes -> labels (N, Q), boxes (N, Q, 4), scores (N, Q)"

    def recognise(self, sig: Signature) -> Recognition | None:
        names = {t.name for t in sig.outputs}
        if not ({"labels", "boxes", "scores"} <= names and any(t.name == TARGET_SIZES for t in sig.inputs)):
            return None
        if sig.task not in (None, "detect"):
            return None
        classes = len(sig.names) if sig.names else len(COCO_CLASSES)  # a label column: the count is not seen
        return Recognition(
            "detect",
            classes,
            Pixels(sig.input_hw, "stretch", rgb=True, scale=1 / 255),
            f"inputs images + {TARGET_SIZES}, outputs labels, boxes, scores: a D-FINE / RT-DETRv2 export, no NMS",
            default_names=COCO_CLASSES,
        )

    def extra_inputs(self, card: ModelCard, placement: Placement) -> dict[str, np.ndarray]:
        h, w = card.pixels.size_hw
        return {TARGET_SIZES: np.array([[w, h]], np.int64)}

    def candidates(self, outputs: Sequence[np.ndarray], card: ModelCard, conf: float) -> Candidates:
        names = [t.name for t in card.outputs]
        labels, boxes, scores = (outputs[names.index(n)] for n in ("labels", "boxes", "scores"))
        labels = labels.reshape(-1).astype(np.int64)
        scores = scores.reshape(-1).astype(np.float32)
        keep = np.flatnonzero((scores > conf) & (labels >= 0) & (labels < card.num_classes))
        return Candidates(boxes.reshape(-1, 4)[keep].astype(np.float32), scores[keep], labels[keep], nms=False)


FAMILY = DFine()
