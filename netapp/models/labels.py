"""Class names: from ONNX metadata, a labels file, or COCO by default."""

from __future__ import annotations

import ast
import json
from pathlib import Path

COCO_CLASSES: tuple[str, ...] = (
    "person",
    "bicycle",
    "car",
    "motorcycle",
    "airplane",
    "bus",
    "train",
    "truck",
    "boat",
    "traffic light",
    "fire hydrant",
    "stop sign",
    "parking meter",
    "bench",
    "bird",
    "cat",
    "dog",
    "horse",
    "sheep",
    "cow",
    "elephant",
    "bear",
    "zebra",
    "giraffe",
    "backpack",
    "umbrella",
    "handbag",
    "tie",
    "suitcase",
    "frisbee",
    "skis",
    "snowboard",
    "sports ball",
    "kite",
    "baseball bat",
    "baseball glove",
    "skateboard",
    "surfboard",
    "tennis racket",
    "bottle",
    "wine glass",
    "cup",
    "fork",
    "knife",
    "spoon",
    "bowl",
    "banana",
    "apple",
    "sandwich",
    "orange",
    "broccoli",
    "carrot",
    "hot dog",
    "pizza",
    "donut",
    "cake",
    "chair",
    "couch",
    "potted plant",
    "bed",
    "dining table",
    "toilet",
    "tv",
    "laptop",
    "mouse",
    "remote",
    "keyboard",
    "cell phone",
    "microwave",
    "oven",
    "toaster",
    "sink",
    "refrigerator",
    "book",
    "clock",
    "vase",
    "scissors",
    "teddy bear",
    "hair drier",
    "toothbrush",
)


# COCO's category ids run 1..90 with ten left unused: DETR-family COCO exports (RF-DETR) score all 91 slots.
COCO91_UNUSED = (0, 12, 26, 29, 30, 45, 66, 68, 69, 71, 83)


def coco91_names() -> list[str]:
    """Class names by COCO category id (0..90); the unused ids are named `unused_ID`."""
    names, known = [], iter(COCO_CLASSES)
    for i in range(91):
        names.append(f"unused_{i}" if i in COCO91_UNUSED else next(known))
    return names


def names_from_metadata(metadata: dict[str, str]) -> list[str] | None:
    """Class names stored by exporters: Ultralytics writes `names` as a Python dict literal, others JSON lists."""
    raw = metadata.get("names") or metadata.get("labels") or metadata.get("classes")
    if not raw:
        return None
    for parse in (json.loads, ast.literal_eval):
        try:
            value = parse(raw)
        except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
            continue
        if isinstance(value, dict):
            try:
                return [str(value[k]) for k in sorted(value, key=lambda k: int(k))]
            except (TypeError, ValueError):
                return None  # keys that are not class indices: no names rather than a wrong order
        if isinstance(value, (list, tuple)):
            return [str(v) for v in value]
    return None


def load_labels(path: str | Path) -> list[str]:
    """A labels file: one name per line (blank lines and `#` comments ignored)."""
    names = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            names.append(line)
    if not names:
        raise ValueError(f"labels file {path} holds no class names")
    return names
