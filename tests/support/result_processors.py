"""Custom SDK processors whose results carry masks, keypoints, oriented boxes and classifications, placed from the
frame's size (no model): what the display paths (client, drawing, live page, MCAP, ROS 2) and the netapp's bounds
are tested with while the model layer that makes them from ONNX models is built beside them."""

from __future__ import annotations

import numpy as np

from netapp.results import MAX_CLASSIFICATIONS, MAX_POLYGON_POINTS, Classification, Detection, Mask, to_wire
from netapp.sdk import Processor

PERSON, DOG = 0, 16
# A standing person's COCO-17 keypoints on a unit box (x, y from its top left), the score of each; the left wrist
# (index 9) is unsure, so drawing skips it.
POSE = (
    (0.50, 0.08), (0.46, 0.05), (0.54, 0.05), (0.42, 0.07), (0.58, 0.07), (0.35, 0.22), (0.65, 0.22), (0.25, 0.38),
    (0.75, 0.38), (0.20, 0.52), (0.80, 0.52), (0.40, 0.55), (0.60, 0.55), (0.38, 0.75), (0.62, 0.75), (0.37, 0.95),
    (0.63, 0.95),
)  # fmt: skip
UNSURE_KEYPOINT = 9


def person_box(width: int, height: int) -> tuple[float, float, float, float]:
    """The person's box: the left half of the frame, with a margin."""
    return 0.1 * width, 0.1 * height, 0.45 * width, 0.9 * height


def dog_box(width: int, height: int) -> tuple[float, float, float, float]:
    """The dog's box: the right part of the frame, in its lower half."""
    return 0.55 * width, 0.5 * height, 0.9 * width, 0.9 * height


def person_keypoints(width: int, height: int) -> list[list[float]]:
    x1, y1, x2, y2 = person_box(width, height)
    return [
        [x1 + u * (x2 - x1), y1 + v * (y2 - y1), 0.1 if i == UNSURE_KEYPOINT else 0.9] for i, (u, v) in enumerate(POSE)
    ]


def dog_mask(width: int, height: int) -> np.ndarray:
    """An ellipse filling the dog's box, as a frame-sized boolean mask."""
    x1, y1, x2, y2 = dog_box(width, height)
    yy, xx = np.mgrid[:height, :width]
    cx, cy, rx, ry = (x1 + x2) / 2, (y1 + y2) / 2, (x2 - x1) / 2, (y2 - y1) / 2
    return ((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2 <= 1


def scene(width: int, height: int) -> dict:
    """The result of a frame of `width` x `height`: a person with a polygon mask (a diamond in its box), keypoints
    and an oriented box; a dog with an RLE mask; and an image classification's top 3."""
    x1, y1, x2, y2 = person_box(width, height)
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
    diamond = [cx, y1, x2, cy, cx, y2, x1, cy]
    person = Detection(
        (x1, y1, x2, y2),
        0.9,
        PERSON,
        "person",
        mask=Mask(polygons=[diamond]),
        keypoints=person_keypoints(width, height),
        rbox=(cx, cy, 0.8 * (x2 - x1), 0.5 * (y2 - y1), 0.5),
    )
    dog = Detection(dog_box(width, height), 0.8, DOG, "dog", mask=Mask.from_array(dog_mask(width, height), fmt="rle"))
    top3 = [Classification(207, "golden retriever", 0.6), Classification(208, "labrador", 0.3)]
    top3.append(Classification(0, "tench", 0.01))
    return {"detections": to_wire([person, dog]), "classifications": to_wire(top3)}


class SceneProcessor(Processor):
    """Every frame's `scene` (see above)."""

    name = "scene"

    def process(self, batch):
        return [scene(image.shape[1], image.shape[0]) for image in batch]


# What a careless or hostile processor may return, one detection per way (its box always fine), and the reason the
# netapp counts each under.
HOSTILE_FIELDS = (
    ("mask", {"polygons": [[1.0, 2.0] * (MAX_POLYGON_POINTS + 1)]}, "mask_too_big"),
    ("mask", {"polygons": [[1.0, 2.0, 3.0]]}, "mask_malformed"),
    ("mask", {"rle": {"size": [10, 10], "counts": "x" * 70_000}}, "mask_too_big"),
    ("mask", "not a mask", "mask_malformed"),
    ("keypoints", [[1.0, 2.0, 0.5]] * 200, "keypoints_too_big"),
    ("keypoints", [[1.0, float("nan"), 0.5]], "keypoints_malformed"),
    ("keypoints", [[1.0, "2", 0.5]], "keypoints_malformed"),
    ("rbox", [1.0, 2.0, 3.0], "rbox_malformed"),
    ("rbox", [1.0, 2.0, 3.0, 4.0, True], "rbox_malformed"),
)


class HostileProcessor(Processor):
    """One detection per `HOSTILE_FIELDS` entry, one fine detection with all three fields, and too many
    classifications."""

    name = "hostile"

    def process(self, batch):
        out = []
        for image in batch:
            height, width = image.shape[:2]
            fine = scene(width, height)["detections"][0]
            bad = [
                {"bbox": [1.0, 1.0, 9.0, 9.0], "score": 0.5, "class": 1, "class_name": "bicycle", name: value}
                for name, value, _ in HOSTILE_FIELDS
            ]
            classes = [{"class": i, "class_name": str(i), "score": 0.001} for i in range(MAX_CLASSIFICATIONS + 7)]
            out.append({"detections": [*bad, fine], "classifications": classes})
        return out
