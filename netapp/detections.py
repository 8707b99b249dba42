"""A result's detections as one columnar type, read from the wire once (`Detections.from_wire`) and written back to
it unchanged (`to_wire`), in the spirit of supervision's `Detections` and Ultralytics' `Results`.

The wire dict (netapp/results.py, 5G-ERA's `bbox`, `score`, `class`, `class_name` plus `mask`, `keypoints`, `rbox`,
`track_id`) stays the edge every transport carries; every reader (drawing, Foxglove, ROS 2, sizing, matching, the
tracker, the stats) takes this type instead of parsing the dicts by hand. `from_wire` validates and bounds the
message once (finite numbers, consistent lengths, bounded counts and sizes), so the columns need no checks:

- `strict=True` (the default) refuses a malformed message with a ValueError that says which detection and field;
- `strict=False` (the displays, which must never raise on what a custom processor sends) sets aside what strict
  would refuse: a detection without a good box is no detection (kept untyped at its place in the list), a bad field
  is no column value (kept untyped in the detection's `data`). Readers see only the well-formed columns; `to_wire`
  still gives back the message as it came, so passing a result through (sizing) changes nothing it did not type.
  One check is left to where it happens anyway: an RLE's runs are checked as it is decoded (`mask_array` gives None
  for one whose runs do not add up), since checking them costs what decoding does (about 1 ms for a 720p mask) and
  most readers (the stats, sizing, the boxes of ROS 2) never decode one. Detections past `MAX_DETECTIONS` stay
  untyped too; a `track_id` on some detections only gives the others `null` (the tracker gives every one its key).

Masks stay as the wire has them (polygons or an RLE, per detection) and are decoded only when a reader asks
(`mask_array`): the displays draw the polygons as they are, and an RLE decoded to a frame-sized array for every
detection would cost each result megabytes that most readers never look at. A reader that decoded its masks already
(the accuracy profile) may hand them in as boolean arrays instead.

Imports nothing from `netapp.client` or `netapp.server`: the netapp, the robot client and the models all use it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from netapp.detection_wire import (
    BBOX_FIELD,
    CLASS_FIELD,
    CLASS_NAME_FIELD,
    SCORE_FIELD,
    TRACK_ID_FIELD,
    WireReader,
)
from netapp.results import (
    DETECTIONS_FIELD,
    KEYPOINT_MIN_SCORE,
    KEYPOINTS_FIELD,
    MASK_FIELD,
    MAX_DETECTIONS,
    MAX_POLYGON_POINTS,
    POLYGONS_KEY,
    RBOX_FIELD,
    RLE_KEY,
    mask_to_array,
    mask_to_polygons,
    oriented_corners,
    skeleton_of,
)


@dataclass(frozen=True, eq=False)
class Detections:
    """N detections as columns, in the robot frame's pixels.

    `xyxy` (N x 4), `confidence` (N; NaN where none was given), `class_id` (N; -1 where none), `class_name` (N
    strings or None), `masks` (N wire masks, boolean arrays or None), `keypoints` (N x K x 3: x, y, score; NaN rows
    where a detection has none; None when none has), `rbox` (N x 5: cx, cy, w, h, angle in radians; NaN rows; None
    when none has), `tracker_id` (N; -1 for a track not yet confirmed; None when not tracked), `data` (N dicts: a
    detection's other keys, a custom processor's own fields, kept as they came)."""

    xyxy: np.ndarray
    confidence: np.ndarray
    class_id: np.ndarray
    class_name: np.ndarray
    masks: np.ndarray
    keypoints: np.ndarray | None = None
    rbox: np.ndarray | None = None
    tracker_id: np.ndarray | None = None
    data: np.ndarray = field(default_factory=lambda: np.empty(0, object))
    # What `from_wire(strict=False)` did not type: (place in the wire list, item), and the rest of the message.
    untyped: tuple[tuple[int, Any], ...] = ()
    message: Mapping[str, Any] | None = None

    # -- the wire ----------------------------------------------------------------------------------------------

    @classmethod
    def from_wire(cls, wire: Any, *, strict: bool = True) -> Detections:
        """A result message (a dict whose `detections` are read, the rest kept for `to_wire`) or its list of
        detections; ValueError naming the first problem (`strict`), or what is malformed set aside (not `strict`)."""
        message: Mapping[str, Any] | None = None
        if isinstance(wire, Mapping):
            message, wire = wire, wire.get(DETECTIONS_FIELD, [])
        if isinstance(wire, Detections):
            return wire
        if not isinstance(wire, (list, tuple)):
            if strict:
                raise ValueError(f"a result's detections must be a list, not {type(wire).__name__}")
            return replace(cls.empty(), message=message)
        if strict and len(wire) > MAX_DETECTIONS:
            raise ValueError(f"a result may carry {MAX_DETECTIONS} detections at most, not {len(wire)}")
        return cls(**WireReader(strict).read(wire), message=message)

    def to_wire(self) -> Any:
        """The detections as the wire carries them: the message `from_wire` read (with these detections), else the
        list. For every message the netapp sends, `Detections.from_wire(x).to_wire() == x`."""
        typed = [self._wire_detection(i) for i in range(len(self))]
        for place, item in self.untyped:  # in order of place: each goes back where it was
            typed.insert(place, item)
        if self.message is None:
            return typed
        if DETECTIONS_FIELD not in self.message and not typed:
            return dict(self.message)
        return {**self.message, DETECTIONS_FIELD: typed}

    def _wire_detection(self, i: int) -> dict[str, Any]:
        out: dict[str, Any] = {BBOX_FIELD: self.xyxy[i].tolist()}
        if not math.isnan(self.confidence[i]):
            out[SCORE_FIELD] = float(self.confidence[i])
        if self.class_id[i] >= 0:
            out[CLASS_FIELD] = int(self.class_id[i])
        if self.class_name[i] is not None:
            out[CLASS_NAME_FIELD] = self.class_name[i]
        mask = self.masks[i]
        if isinstance(mask, np.ndarray):
            from netapp.results import mask_to_rle

            out[MASK_FIELD] = {"rle": mask_to_rle(mask)}  # a mask decoded in-process goes back exact
        elif mask is not None:
            out[MASK_FIELD] = mask
        if self.keypoints is not None and not np.isnan(self.keypoints[i, 0, 0]):
            out[KEYPOINTS_FIELD] = self.keypoints[i].tolist()
        if self.rbox is not None and not np.isnan(self.rbox[i, 0]):
            out[RBOX_FIELD] = self.rbox[i].tolist()
        if self.tracker_id is not None:
            out[TRACK_ID_FIELD] = int(self.tracker_id[i]) if self.tracker_id[i] >= 0 else None
        out.update(self.data[i])
        return out

    @classmethod
    def empty(cls) -> Detections:
        return cls(
            xyxy=np.zeros((0, 4)),
            confidence=np.zeros(0),
            class_id=np.zeros(0, np.int64),
            class_name=np.empty(0, object),
            masks=np.empty(0, object),
        )

    @classmethod
    def merge(cls, parts: Sequence[Detections]) -> Detections:
        """The detections of `parts`, one after another (the untyped items and messages stay behind). A column some
        parts lack is filled as for a detection without it; keypoints of different skeletons are a ValueError."""
        parts = [p for p in parts if len(p)] or [cls.empty()]
        counts = {p.keypoints.shape[1] for p in parts if p.keypoints is not None}
        if len(counts) > 1:
            raise ValueError(f"cannot merge detections of different skeletons ({sorted(counts)} keypoints)")

        def column(name: str, fill: Any, shape: tuple[int, ...]) -> np.ndarray | None:
            if all(getattr(p, name) is None for p in parts):
                return None
            blank = [np.full((len(p), *shape), fill) for p in parts]
            return np.concatenate(
                [getattr(p, name) if getattr(p, name) is not None else b for p, b in zip(parts, blank, strict=True)]
            )

        return cls(
            xyxy=np.concatenate([p.xyxy for p in parts]),
            confidence=np.concatenate([p.confidence for p in parts]),
            class_id=np.concatenate([p.class_id for p in parts]),
            class_name=np.concatenate([p.class_name for p in parts]),
            masks=np.concatenate([p.masks for p in parts]),
            keypoints=column("keypoints", np.nan, (next(iter(counts), 0), 3)),
            rbox=column("rbox", np.nan, (5,)),
            tracker_id=column("tracker_id", -1, ()),
            data=np.concatenate([p.data for p in parts]),
        )

    # -- a list of detections ----------------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.xyxy)

    def __getitem__(self, index: Any) -> Detections:
        """The detections `index` selects (a boolean mask, indices, a slice or one index), as Detections: the
        untyped items and the message stay behind (they have no place in a selection)."""
        picked = np.arange(len(self))[index]
        picked = np.atleast_1d(picked)

        def pick(column: np.ndarray | None) -> np.ndarray | None:
            return None if column is None else column[picked]

        return Detections(
            xyxy=self.xyxy[picked],
            confidence=self.confidence[picked],
            class_id=self.class_id[picked],
            class_name=self.class_name[picked],
            masks=self.masks[picked],
            keypoints=pick(self.keypoints),
            rbox=pick(self.rbox),
            tracker_id=pick(self.tracker_id),
            data=self.data[picked],
        )

    def wire_places(self) -> np.ndarray:
        """N indices: where each detection stood in the wire list `from_wire` read (after the untyped items are
        left out, the i-th detection need not be the i-th item)."""
        untyped = np.fromiter((place for place, _ in self.untyped), np.int64, len(self.untyped))
        return np.setdiff1d(np.arange(len(self) + len(untyped)), untyped)

    def has_keypoints(self) -> np.ndarray:
        """N booleans: which detections carry keypoints."""
        return np.zeros(len(self), bool) if self.keypoints is None else ~np.isnan(self.keypoints[:, 0, 0])

    def has_rbox(self) -> np.ndarray:
        """N booleans: which detections carry an oriented box."""
        return np.zeros(len(self), bool) if self.rbox is None else ~np.isnan(self.rbox[:, 0])

    def has_mask(self) -> np.ndarray:
        """N booleans: which detections carry a mask."""
        return np.fromiter((m is not None for m in self.masks), bool, len(self))

    def has_rle(self) -> bool:
        """Whether a mask is an RLE (decoded at the frame's size, where polygons need no size)."""
        return any(isinstance(m, Mapping) and RLE_KEY in m for m in self.masks)

    # -- what the readers read ---------------------------------------------------------------------------------

    def label(self, i: int) -> str:
        """`person 0.91`: the class name (else its id) and the score, as every display writes it."""
        name = self.class_name[i] if self.class_name[i] is not None else self.class_text(i)
        return label_text(name, None if math.isnan(self.confidence[i]) else float(self.confidence[i]))

    def class_text(self, i: int) -> str:
        """The class as a word: its name, else its id, else `?`."""
        if self.class_name[i] is not None:
            return self.class_name[i]
        return str(int(self.class_id[i])) if self.class_id[i] >= 0 else "?"

    def rbox_corners(self) -> np.ndarray:
        """N x 4 x 2: each oriented box's corners (NaN for a detection without one)."""
        if self.rbox is None:
            return np.full((len(self), 4, 2), np.nan)
        return oriented_corners(self.rbox)

    def pose(
        self, i: int, min_score: float = KEYPOINT_MIN_SCORE
    ) -> tuple[list[tuple[float, float]], list[tuple[tuple[float, float], tuple[float, float]]]]:
        """Detection `i`'s sure keypoints (score >= `min_score`) and the skeleton's limbs between them (both ends
        sure); nothing when it has no keypoints."""
        if self.keypoints is None or np.isnan(self.keypoints[i, 0, 0]):
            return [], []
        points = self.keypoints[i]
        sure = [(float(x), float(y)) if s >= min_score else None for x, y, s in points.tolist()]
        limbs = [(sure[a], sure[b]) for a, b in skeleton_of(len(sure)) if sure[a] is not None and sure[b] is not None]
        return [p for p in sure if p is not None], limbs  # type: ignore[misc]

    def mask_array(self, i: int, height: int, width: int) -> np.ndarray | None:
        """Detection `i`'s mask as a boolean `height` x `width` array of the frame (None: it has none, or, read
        leniently, its RLE's runs do not add up). An RLE of another size is resized to it; a mask handed in decoded
        is returned as it is."""
        mask = self.masks[i]
        if mask is None or isinstance(mask, np.ndarray):
            return mask
        try:
            return mask_to_array(mask, height, width)
        except ValueError:  # an RLE's runs, checked as it decodes (`from_wire(strict=False)` leaves them to it)
            return None

    def mask_outlines(self, i: int, height: int, width: int) -> list[list[float]]:
        """Detection `i`'s mask as flat polygons of a `height` x `width` frame: its polygons as they are, an RLE's
        outline traced; none when it has no mask."""
        mask = self.masks[i]
        if isinstance(mask, Mapping) and POLYGONS_KEY in mask:
            return [p for p in mask[POLYGONS_KEY] if len(p) >= 6]
        array = self.mask_array(i, height, width)
        return [] if array is None else mask_to_polygons(array, max_points=MAX_POLYGON_POINTS)

    # -- new detections from these ---------------------------------------------------------------------------

    def scaled(self, sx: float, sy: float) -> Detections:
        """These detections in a frame `sx` x `sy` times the size (rounded to 0.1 pixel, as the netapp writes them):
        boxes, polygons, keypoints' x and y, oriented boxes (their sides by the mean scale: a robot keeps the aspect
        ratio, so sx and sy differ only by rounding). An RLE stays at the size it was found at (`mask_array` resizes
        it); the untyped items and fields stay as they came."""
        s = (sx + sy) / 2
        keypoints = None
        if self.keypoints is not None:
            keypoints = self.keypoints.copy()
            keypoints[..., :2] = np.round(keypoints[..., :2] * (sx, sy), 1)
        rbox = None
        if self.rbox is not None:
            rbox = self.rbox.copy()
            rbox[:, :4] = np.round(rbox[:, :4] * (sx, sy, s, s), 1)
        masks = np.empty(len(self), object)
        masks[:] = [_scaled_mask(m, sx, sy) for m in self.masks]
        return replace(
            self, xyxy=np.round(self.xyxy * (sx, sy, sx, sy), 1), keypoints=keypoints, rbox=rbox, masks=masks
        )

    def with_tracker_id(self, tracker_id: Sequence[int] | np.ndarray) -> Detections:
        """These detections with a track id each (-1: not yet confirmed), the rest as it was."""
        ids = np.asarray(tracker_id, np.int64).reshape(-1)
        if len(ids) != len(self):
            raise ValueError(f"{len(ids)} track ids for {len(self)} detections")
        return replace(self, tracker_id=ids)


def label_text(name: Any, score: float | None) -> str:
    """`name 0.91`, or the name alone without a score."""
    return f"{name} {score:.2f}" if score is not None else str(name)


def as_detections(value: Detections | Mapping[str, Any] | Iterable[Any]) -> Detections:
    """`value` itself, or the wire's detections (a message or a list) read leniently (`from_wire(strict=False)`)."""
    if isinstance(value, Detections):
        return value
    return Detections.from_wire(value if isinstance(value, Mapping) else list(value), strict=False)


def _scaled_mask(mask: Any, sx: float, sy: float) -> Any:
    if not isinstance(mask, Mapping) or POLYGONS_KEY not in mask:
        return mask
    polygons = []
    for flat in mask[POLYGONS_KEY]:
        points = np.asarray(flat, np.float64).reshape(-1, 2) * (sx, sy)
        polygons.append(np.round(points, 1).ravel().tolist())
    return {POLYGONS_KEY: polygons}
