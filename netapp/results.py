"""What a result carries on every transport: detections with masks, keypoints and oriented boxes, and classifications.

The one definition of those fields, shared by the SDK (a processor author returns `Detection`s and
`Classification`s), the netapp (which bounds what it sends: `bound_detections`) and every reader, which takes a
result's detections as one columnar type, `netapp.detections.Detections`, checked with these bounds. A detection
keeps the 5G-ERA schema (`bbox`, `score`, `class`, `class_name`); the rest rides as extra keys, which 5G-ERA robots
ignore. Every coordinate is in the robot's own frame pixels.

    {"bbox": [x1, y1, x2, y2], "score": 0.91, "class": 0, "class_name": "person",
     "mask": {"polygons": [[x, y, x, y, ...], ...]},            # or {"rle": {"size": [h, w], "counts": "..."}}
     "keypoints": [[x, y, score], ...],                          # per the model's skeleton (COCO-17 by default)
     "rbox": [cx, cy, w, h, angle]}                              # an oriented box, angle in radians
    result["classifications"] = [{"class": 207, "class_name": "golden retriever", "score": 0.83}, ...]  # top k

Imports nothing from `netapp.server`: the robot client uses it too.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from itertools import chain
from typing import Any

import cv2
import numpy as np

DETECTIONS_FIELD = "detections"
CLASSIFICATIONS_FIELD = "classifications"
MASK_FIELD = "mask"
KEYPOINTS_FIELD = "keypoints"
RBOX_FIELD = "rbox"
POLYGONS_KEY = "polygons"
RLE_KEY = "rle"
MASK_FORMATS = ("polygons", "rle")

# Bounds on what one detection may carry, checked by the netapp before a result leaves (a custom processor's field
# past them is refused and counted, never sent) and by the client before it draws one.
MAX_POLYGON_POINTS = 1000  # over all of a mask's polygons; the netapp simplifies its own masks to fit
MAX_POLYGONS = 32
MAX_RLE_CHARS = 64 * 1024
MAX_MASK_SIDE = 16384  # an RLE's height and width
MAX_KEYPOINTS = 133  # COCO-WholeBody, the largest common skeleton
MAX_CLASSIFICATIONS = 100
MAX_DETECTIONS = 1000

# COCO's 17 person keypoints and the limbs between them (0-based), the default skeleton of a pose model.
COCO_KEYPOINTS = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
    "right_ankle",
)  # fmt: skip
KEYPOINT_MIN_SCORE = 0.5  # what the displays (drawing, the live page, Foxglove) leave out as unsure
MASK_ALPHA = 0.45  # a mask's fill over the picture in the displays: the object stays visible through it
COCO_SKELETON = (
    (15, 13), (13, 11), (16, 14), (14, 12), (11, 12), (5, 11), (6, 12), (5, 6), (5, 7), (6, 8), (7, 9), (8, 10),
    (1, 2), (0, 1), (0, 2), (1, 3), (2, 4), (3, 5), (4, 6),
)  # fmt: skip


@dataclass
class Mask:
    """An instance mask in frame pixels: COCO-style polygons (flat `[x, y, x, y, ...]` lists) or a COCO RLE."""

    polygons: list[list[float]] | None = None
    rle: dict[str, Any] | None = None

    def to_wire(self) -> dict[str, Any]:
        return {RLE_KEY: self.rle} if self.rle is not None else {POLYGONS_KEY: self.polygons or []}

    @classmethod
    def from_array(
        cls, mask: np.ndarray, *, fmt: str = "polygons", max_points: int = MAX_POLYGON_POINTS, origin=(0.0, 0.0)
    ) -> Mask:
        """A boolean HxW mask (whose pixel (0, 0) sits at `origin` in the frame) as polygons or an RLE."""
        if fmt == "rle":
            if origin != (0.0, 0.0):
                raise ValueError("an RLE mask covers the whole frame: give it the frame-sized mask")
            return cls(rle=mask_to_rle(mask))
        return cls(polygons=mask_to_polygons(mask, max_points=max_points, origin=origin))


@dataclass
class Detection:
    """One detected object. `bbox` is (x1, y1, x2, y2) in frame pixels; the rest is what the model gives."""

    bbox: Sequence[float]
    score: float
    class_id: int
    class_name: str
    mask: Mask | None = None
    keypoints: np.ndarray | Sequence[Sequence[float]] | None = None  # K x 3: x, y, score
    rbox: Sequence[float] | None = None  # cx, cy, w, h, angle (radians)
    extra: dict[str, Any] = field(default_factory=dict)

    def to_wire(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "bbox": [round(float(v), 1) for v in self.bbox],
            "score": round(float(self.score), 4),
            "class": int(self.class_id),
            "class_name": self.class_name,
        }
        if self.mask is not None:
            out[MASK_FIELD] = self.mask.to_wire()
        if self.keypoints is not None:
            out[KEYPOINTS_FIELD] = [
                [round(float(x), 1), round(float(y), 1), round(float(s), 3)] for x, y, s in self.keypoints
            ]
        if self.rbox is not None:
            cx, cy, w, h, angle = (float(v) for v in self.rbox)
            out[RBOX_FIELD] = [round(cx, 1), round(cy, 1), round(w, 1), round(h, 1), round(angle, 4)]
        out.update(self.extra)
        return out


@dataclass
class Classification:
    """One of an image classifier's top k."""

    class_id: int
    class_name: str
    score: float

    def to_wire(self) -> dict[str, Any]:
        return {"class": int(self.class_id), "class_name": self.class_name, "score": round(float(self.score), 4)}


def to_wire(items: Iterable[Detection | Classification | dict[str, Any]]) -> list[dict[str, Any]]:
    """A processor's detections or classifications as the dicts a result carries (dicts pass through)."""
    return [item if isinstance(item, dict) else item.to_wire() for item in items]


# --- masks -------------------------------------------------------------------------------------------------------


def mask_to_polygons(
    mask: np.ndarray, *, max_points: int = MAX_POLYGON_POINTS, origin: Sequence[float] = (0.0, 0.0)
) -> list[list[float]]:
    """The outer contours of a boolean mask as flat COCO polygons, at most `max_points` points over all of them.

    Each contour is simplified (Douglas-Peucker, a tolerance that doubles until the budget fits), the largest kept
    first; pieces under 3 points are dropped. `origin` shifts them into the frame (a mask cut to its box).
    """
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    contours = sorted(contours, key=cv2.contourArea, reverse=True)[:MAX_POLYGONS]
    tolerance = 0.5
    while True:
        simplified = [cv2.approxPolyDP(c, tolerance, True) if len(c) > 3 else c for c in contours]
        simplified = [c for c in simplified if len(c) >= 3]
        if sum(len(c) for c in simplified) <= max_points or tolerance > max(mask.shape):
            break
        tolerance *= 2
    polygons, budget = [], max_points
    ox, oy = float(origin[0]), float(origin[1])
    for contour in simplified:
        if len(contour) > budget:
            break
        budget -= len(contour)
        points = contour.reshape(-1, 2).astype(np.float64) + (ox, oy)
        polygons.append(np.round(points.reshape(-1), 1).tolist())  # one call, not one per value: 20 masks' worth
    return polygons


def mask_to_rle(mask: np.ndarray) -> dict[str, Any]:
    """A boolean HxW mask as COCO's compressed RLE (`{"size": [h, w], "counts": str}`), as pycocotools writes it."""
    from pycocotools import mask as coco_mask

    rle = coco_mask.encode(np.asfortranarray(mask.astype(np.uint8)))
    return {"size": [int(v) for v in rle["size"]], "counts": rle["counts"].decode("ascii")}


def rle_counts(counts: str, height: int, width: int) -> np.ndarray:
    """The run lengths of a compressed COCO RLE string (pycocotools' `rleFrString`, vectorised), checked: each char
    in the alphabet, no number cut off at the end, no run negative, and the runs adding up to height x width.

    The check is the point: pycocotools' own decoder trusts the string, and a hostile one corrupts its heap (seen
    here: a random 40-character string aborted Python), so no RLE from the network reaches it.
    """
    if len(counts) > MAX_RLE_CHARS:
        raise ValueError(f"an RLE's counts may have {MAX_RLE_CHARS} characters at most")
    if not counts.isascii():
        raise ValueError("an RLE's counts must be ASCII")
    c = np.frombuffer(counts.encode("ascii"), np.uint8).astype(np.int64) - 48
    if c.size == 0 or c.min() < 0 or c.max() > 63:
        raise ValueError("an RLE's counts must be characters '0' to 'o'")
    last = (c & 0x20) == 0  # the last character of each number
    if not last[-1]:
        raise ValueError("an RLE's counts end in the middle of a number")
    ends = np.flatnonzero(last)
    starts = np.concatenate(([0], ends[:-1] + 1))
    digits = ends - starts + 1
    if digits.max() > 7:  # 35 bits: more than any run of a mask within the bounds
        raise ValueError("an RLE's counts hold a number too long")
    group = np.repeat(np.arange(ends.size), digits)
    shift = 5 * (np.arange(c.size) - starts[group])
    x = np.zeros(ends.size, np.int64)
    np.add.at(x, group, (c & 0x1F) << shift)
    negative = (c[ends] & 0x10) != 0
    x[negative] -= np.int64(1) << (5 * digits[negative])  # sign extension of the last 5-bit digit
    runs = x.copy()  # from the third run on, each is a difference from the run two before
    runs[1::2] = np.cumsum(x[1::2])
    runs[2::2] = np.cumsum(x[2::2])
    if runs.min() < 0 or int(runs.sum()) != height * width:
        raise ValueError("an RLE's runs must be non-negative and add up to height x width")
    return runs


def rle_to_array(rle: dict[str, Any]) -> np.ndarray:
    """A COCO RLE (compressed string or uncompressed list of counts) as a boolean HxW mask; ValueError when it is
    not one or is larger than the bounds."""
    size, counts = rle.get("size"), rle.get("counts")
    if (
        not isinstance(size, (list, tuple))
        or len(size) != 2
        or not all(isinstance(v, int) and 0 < v <= MAX_MASK_SIDE for v in size)
    ):
        raise ValueError(f"an RLE's size must be [height, width], each 1..{MAX_MASK_SIDE}")
    height, width = size
    if isinstance(counts, str):
        runs = rle_counts(counts, height, width)
    elif isinstance(counts, list) and all(isinstance(c, int) and c >= 0 for c in counts):
        if sum(counts) != height * width:
            raise ValueError("an uncompressed RLE's counts must add up to height x width")
        runs = np.asarray(counts, np.int64)
    else:
        raise ValueError("an RLE's counts must be a string (compressed) or a list of counts")
    values = np.arange(runs.size) % 2 == 1  # runs alternate, background first
    return np.repeat(values, runs).reshape(width, height).T  # column-major, as COCO counts


def polygons_to_array(polygons: Sequence[Sequence[float]], height: int, width: int) -> np.ndarray:
    """Flat polygons filled into a boolean HxW mask (how a mask sent as polygons is drawn or compared)."""
    out = np.zeros((height, width), np.uint8)
    pts = [np.round(np.asarray(p, np.float64).reshape(-1, 2)).astype(np.int32) for p in polygons if len(p) >= 6]
    if pts:
        cv2.fillPoly(out, pts, 1)
    return out.astype(bool)


def mask_to_array(mask: dict[str, Any], height: int, width: int) -> np.ndarray:
    """A result's `mask` field (either form) as a boolean HxW mask of the frame; ValueError when malformed."""
    if RLE_KEY in mask:
        array = rle_to_array(mask[RLE_KEY])
        if array.shape != (height, width):
            array = cv2.resize(array.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)
        return array
    return polygons_to_array(mask.get(POLYGONS_KEY) or [], height, width)


# --- bounds ------------------------------------------------------------------------------------------------------


_NUMBER_TYPES = frozenset({int, float, np.float64})  # what a field's numbers may be (no bool, no string)


def finite_numbers(values: Any, length: int | None = None) -> bool:
    """Whether `values` is a list (or tuple) of `length` finite numbers (int or float, never bool or str)."""
    if not isinstance(values, (list, tuple)) or (length is not None and len(values) != length):
        return False
    # The types by a set, finiteness by the sum (NaN, inf and an overflow carry through it): a 2,000-number
    # polygon in ~20 us, where a check per value took ten times that on the event loop.
    if not set(map(type, values)) <= _NUMBER_TYPES:
        return False
    try:
        return math.isfinite(sum(values))
    except OverflowError:  # an int too large for a float
        return False


def field_problem(name: str, value: Any, rle_runs: bool = True) -> str | None:
    """Why a detection's mask, keypoints or rbox field may not be sent (too big or malformed); None when fine.
    Without `rle_runs`, an RLE's runs are left to be checked where it is decoded (`rle_counts`): the rest is cheap,
    that check is not (about 1 ms for a 720p mask)."""
    if name == MASK_FIELD:
        if not isinstance(value, dict) or len(value) != 1 or not ({POLYGONS_KEY, RLE_KEY} & value.keys()):
            return "mask_malformed"
        if RLE_KEY in value:
            rle = value[RLE_KEY]
            if not isinstance(rle, dict) or not isinstance(rle.get("counts"), str):
                return "mask_malformed"
            if len(rle["counts"]) > MAX_RLE_CHARS:
                return "mask_too_big"
            size = rle.get("size")
            if not finite_numbers(size, 2) or not all(isinstance(v, int) and 0 < v <= MAX_MASK_SIDE for v in size):
                return "mask_malformed"
            if not rle_runs:
                return None if rle["counts"].isascii() else "mask_malformed"
            try:
                rle_counts(rle["counts"], *size)
            except ValueError:
                return "mask_malformed"
            return None
        polygons = value[POLYGONS_KEY]
        if not isinstance(polygons, list):
            return "mask_malformed"
        if len(polygons) > MAX_POLYGONS:
            return "mask_too_big"
        # Shapes polygon by polygon, then the numbers of all of them in one check (one per polygon cost 3x as much
        # on a result of 20 masks); the reason is the one a check polygon by polygon would give first.
        points = 0
        for k, polygon in enumerate(polygons):
            if not isinstance(polygon, list):
                return "mask_malformed"
            points += len(polygon) // 2
            if points > MAX_POLYGON_POINTS:
                return "mask_too_big" if finite_numbers(list(chain.from_iterable(polygons[:k]))) else "mask_malformed"
            if len(polygon) % 2:
                return "mask_malformed"
        return None if finite_numbers(list(chain.from_iterable(polygons))) else "mask_malformed"
    if name == KEYPOINTS_FIELD:
        if not isinstance(value, list):
            return "keypoints_malformed"
        if len(value) > MAX_KEYPOINTS:
            return "keypoints_too_big"
        return None if all(finite_numbers(k, 3) for k in value) else "keypoints_malformed"
    if name == RBOX_FIELD:
        return None if finite_numbers(value, 5) else "rbox_malformed"
    return None


def bound_detections(detections: list[Any]) -> tuple[list[Any], list[str]]:
    """The detections a result may send, and why each field or detection left out was refused.

    A mask, keypoints or rbox field that is too big or malformed is removed from its detection (the box still goes,
    so a 5G-ERA robot loses nothing it knew); detections past `MAX_DETECTIONS` are cut. The caller counts the reasons.
    """
    refused: list[str] = []
    if len(detections) > MAX_DETECTIONS:
        refused.extend(["too_many_detections"] * (len(detections) - MAX_DETECTIONS))
        detections = detections[:MAX_DETECTIONS]
    out = []
    for detection in detections:
        if isinstance(detection, dict) and ({MASK_FIELD, KEYPOINTS_FIELD, RBOX_FIELD} & detection.keys()):
            named = [n for n in (MASK_FIELD, KEYPOINTS_FIELD, RBOX_FIELD) if n in detection]
            problems = {n: p for n in named if (p := field_problem(n, detection[n]))}
            if problems:
                detection = {k: v for k, v in detection.items() if k not in problems}
                refused.extend(problems.values())
        out.append(detection)
    return out, refused


def bound_result(output: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """A processor's output for one frame as a result may send it, and why each part left out was refused.

    Its `detections` go through `bound_detections`; its `classifications` are cut to `MAX_CLASSIFICATIONS` (and
    dropped when not a list). The output is copied only when something changes.
    """
    refused: list[str] = []
    out = output
    detections = output.get(DETECTIONS_FIELD)
    if isinstance(detections, list):
        kept, refused = bound_detections(detections)
        if refused:
            out = {**output, DETECTIONS_FIELD: kept}
    if CLASSIFICATIONS_FIELD in output:
        classifications = output[CLASSIFICATIONS_FIELD]
        if not isinstance(classifications, list):
            out = {k: v for k, v in out.items() if k != CLASSIFICATIONS_FIELD}
            refused.append("classifications_malformed")
        elif len(classifications) > MAX_CLASSIFICATIONS:
            out = {**out, CLASSIFICATIONS_FIELD: classifications[:MAX_CLASSIFICATIONS]}
            refused.extend(["too_many_classifications"] * (len(classifications) - MAX_CLASSIFICATIONS))
    return out, refused


# --- what the displays draw (through `Detections`: the robot's drawing, Foxglove; the live page's draw.js alike) --


def skeleton_of(keypoint_count: int) -> tuple[tuple[int, int], ...]:
    """The limbs between a pose's keypoints: COCO's for 17, none known for another skeleton (points only)."""
    return COCO_SKELETON if keypoint_count == len(COCO_KEYPOINTS) else ()


def oriented_corners(rboxes: np.ndarray) -> np.ndarray:
    """N x 5 oriented boxes (cx, cy, w, h, angle in radians) -> their N x 4 x 2 corners, clockwise in image
    coordinates from the top left before rotation."""
    rboxes = np.asarray(rboxes, np.float64).reshape(-1, 5)
    cx, cy, w, h, angle = (rboxes[:, k : k + 1] for k in range(5))
    c, s = np.cos(angle), np.sin(angle)
    dx = np.concatenate((-w, w, w, -w), axis=1) / 2
    dy = np.concatenate((-h, -h, h, h), axis=1) / 2
    return np.stack((cx + dx * c - dy * s, cy + dx * s + dy * c), axis=2)


def rbox_corners(rbox: Any) -> list[tuple[float, float]]:
    """An `rbox` field's four corners (`[cx, cy, w, h, angle in radians]`); none for a malformed field."""
    if field_problem(RBOX_FIELD, rbox) is not None:
        return []
    return [(float(x), float(y)) for x, y in oriented_corners(np.asarray(rbox, np.float64))[0].tolist()]
