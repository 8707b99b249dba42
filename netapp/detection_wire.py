"""How a result's wire list becomes the columns of `netapp.detections.Detections`: each detection's fields checked
once against `netapp.results`' bounds, with a message that names the detection and the field (`strict`), or what is
malformed set aside untyped (not `strict`). Pure; imports only `netapp.results`."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from netapp.results import (
    KEYPOINTS_FIELD,
    MASK_FIELD,
    MAX_DETECTIONS,
    RBOX_FIELD,
    field_problem,
    finite_numbers,
)

# the 5G-ERA fields of a detection, and the tracker's
BBOX_FIELD = "bbox"
SCORE_FIELD = "score"
CLASS_FIELD = "class"
CLASS_NAME_FIELD = "class_name"
TRACK_ID_FIELD = "track_id"
TYPED_FIELDS = (BBOX_FIELD, SCORE_FIELD, CLASS_FIELD, CLASS_NAME_FIELD, MASK_FIELD, KEYPOINTS_FIELD, RBOX_FIELD)
MAX_CLASS_NAME_CHARS = 256
PROBLEM_TEXT = {
    "mask_malformed": "must be {'polygons': [[x, y, ...], ...]} or {'rle': {'size': [h, w], 'counts': str}}",
    "mask_too_big": "is over the bounds (32 polygons, 1000 points, an RLE of 64 KiB)",
    "keypoints_malformed": "must be a list of [x, y, score], each a finite number",
    "keypoints_too_big": "holds more keypoints than the bounds allow (133)",
    "rbox_malformed": "must be [cx, cy, w, h, angle], five finite numbers",
}


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _is_finite(value: Any) -> bool:
    return finite_numbers([value])


class WireReader:
    """One pass over a wire list: each detection's fields checked once, into columns (`strict`: the first problem
    raised as a ValueError that names the detection and the field)."""

    def __init__(self, strict: bool) -> None:
        self.strict = strict

    def refuse(self, where: str, what: str) -> None:
        if self.strict:
            raise ValueError(f"{where}: {what}")

    def read(self, wire: Sequence[Any]) -> dict[str, Any]:
        """The columns of `Detections` (and its `untyped` items) from a wire list."""
        boxes, scores, classes, names, masks, points, rboxes, tracks, datas = ([] for _ in range(9))
        untyped: list[tuple[int, Any]] = []
        keypoint_count: int | None = None
        for place, item in enumerate(wire):
            where = f"detection {place}"
            if place >= MAX_DETECTIONS:  # not strict: past the bound, kept as it came
                untyped.append((place, item))
                continue
            if not isinstance(item, Mapping):
                self.refuse(where, f"must be an object, not {type(item).__name__}")
                untyped.append((place, item))
                continue
            box = item.get(BBOX_FIELD)
            if not finite_numbers(box, 4):
                self.refuse(where, "'bbox' must be [x1, y1, x2, y2], four finite numbers")
                untyped.append((place, item))
                continue
            data = {k: v for k, v in item.items() if k not in TYPED_FIELDS and k != TRACK_ID_FIELD}
            boxes.append(box)
            scores.append(self.score(item, where, data))
            classes.append(self.class_id(item, where, data))
            names.append(self.class_name(item, where, data))
            masks.append(self.field(item, MASK_FIELD, where, data))
            rbox = self.field(item, RBOX_FIELD, where, data)
            rboxes.append(rbox)
            keypoints = self.field(item, KEYPOINTS_FIELD, where, data)
            if keypoints is not None:
                if not keypoints:
                    self.refuse(where, "'keypoints' must not be empty")
                    data[KEYPOINTS_FIELD], keypoints = item[KEYPOINTS_FIELD], None
                elif keypoint_count is None:
                    keypoint_count = len(keypoints)
                elif len(keypoints) != keypoint_count:
                    self.refuse(where, f"has {len(keypoints)} keypoints where the others have {keypoint_count}")
                    data[KEYPOINTS_FIELD], keypoints = item[KEYPOINTS_FIELD], None
            points.append(keypoints)
            tracks.append(self.track_id(item, where, data))
            datas.append(data)
        n = len(boxes)
        return dict(
            xyxy=np.asarray(boxes, np.float64).reshape(n, 4),
            confidence=np.asarray(scores, np.float64).reshape(n),
            class_id=np.asarray(classes, np.int64).reshape(n),
            class_name=_objects(names),
            masks=_objects(masks),
            keypoints=_keypoint_column(points, keypoint_count),
            rbox=_optional_rows(rboxes, 5),
            tracker_id=self.track_column(tracks),
            data=_objects(datas),
            untyped=tuple(untyped),
        )

    def score(self, item: Mapping[str, Any], where: str, data: dict[str, Any]) -> float:
        if SCORE_FIELD not in item:
            return math.nan
        value = item[SCORE_FIELD]
        if _is_finite(value):
            return float(value)
        self.refuse(where, "'score' must be a finite number")
        data[SCORE_FIELD] = value
        return math.nan

    def class_id(self, item: Mapping[str, Any], where: str, data: dict[str, Any]) -> int:
        if CLASS_FIELD not in item:
            return -1
        value = item[CLASS_FIELD]
        if _is_int(value) and value >= 0:
            return int(value)
        self.refuse(where, "'class' must be a non-negative integer")
        data[CLASS_FIELD] = value
        return -1

    def class_name(self, item: Mapping[str, Any], where: str, data: dict[str, Any]) -> str | None:
        if CLASS_NAME_FIELD not in item:
            return None
        value = item[CLASS_NAME_FIELD]
        if isinstance(value, str) and len(value) <= MAX_CLASS_NAME_CHARS:
            return value
        self.refuse(where, f"'class_name' must be a string of {MAX_CLASS_NAME_CHARS} characters at most")
        data[CLASS_NAME_FIELD] = value
        return None

    def field(self, item: Mapping[str, Any], name: str, where: str, data: dict[str, Any]) -> Any:
        """A mask, keypoints or rbox field when it is within the bounds (a mask handed in decoded as a 2-D boolean
        array too); None when absent or refused."""
        if name not in item:
            return None
        value = item[name]
        if name == MASK_FIELD and isinstance(value, np.ndarray) and value.ndim == 2 and value.dtype == bool:
            return value
        problem = field_problem(name, value, rle_runs=self.strict)
        if problem is None:
            return value
        self.refuse(where, f"'{name}' {PROBLEM_TEXT[problem]}")
        data[name] = value
        return None

    def track_id(self, item: Mapping[str, Any], where: str, data: dict[str, Any]) -> int | None:
        """A track id (-1: the key with null, not yet confirmed); None when the detection has no such key."""
        if TRACK_ID_FIELD not in item:
            return None
        value = item[TRACK_ID_FIELD]
        if value is None:
            return -1
        if _is_int(value) and value >= 0:
            return int(value)
        self.refuse(where, "'track_id' must be a non-negative integer or null")
        data[TRACK_ID_FIELD] = value
        return None

    def track_column(self, tracks: list[int | None]) -> np.ndarray | None:
        if all(t is None for t in tracks):
            return None
        if any(t is None for t in tracks):
            self.refuse("track_id", "a tracked result gives every detection a 'track_id' (null until confirmed)")
        return np.asarray([-1 if t is None else t for t in tracks], np.int64)


def _objects(values: list[Any]) -> np.ndarray:
    out = np.empty(len(values), object)
    out[:] = values
    return out


def _optional_rows(rows: list[Any], width: int) -> np.ndarray | None:
    if all(r is None for r in rows):
        return None
    out = np.full((len(rows), width), np.nan)
    for i, row in enumerate(rows):
        if row is not None:
            out[i] = row
    return out


def _keypoint_column(rows: list[Any], count: int | None) -> np.ndarray | None:
    if count is None:
        return None
    out = np.full((len(rows), count, 3), np.nan)
    for i, row in enumerate(rows):
        if row is not None:
            out[i] = row
    return out
