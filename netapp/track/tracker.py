"""Multi-object tracking of one robot's detections, with a state that survives a move to another netapp.

ByteTrack from Roboflow's `trackers` (its Kalman filter, two-stage association and id allocation). What this
module adds is the state as JSON data: each live track's filter state (the state vector and its covariance,
through the library's `get_state`/`set_state`), its counters and id, and the tracker's next id and last
timestamp. The filter's other matrices are not state: they follow from the tracker's settings. So a tracker
restored from `to_json()` continues exactly where the saved one was, and its track ids continue.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from netapp.detections import Detections

STATE_VERSION = 1
# One track: [id, age, frames since update, seconds since update, consecutive updates, state(8), covariance(36)]
_TRACK_FIELDS = 5
_DIM = 8  # XYXY state: x1, y1, x2, y2 and their velocities
_UPPER = np.triu_indices(_DIM)


@dataclass(frozen=True)
class TrackerConfig:
    """ByteTrack's settings. `lost_track_s`: how long a track unseen is kept (then its id is retired)."""

    lost_track_s: float = 1.0
    frame_rate: float = 30.0  # the frame rate the Kalman model's noise is tuned for; timestamps set the real one
    # Below the library's 0.7 / 0.6: YOLOX-Nano scores people lower than the large detectors ByteTrack was tuned on.
    activation_conf: float = 0.5  # lowest score that starts a track
    high_conf: float = 0.5  # detections above are matched first, the others only to tracks left over
    min_iou: float = 0.1
    min_frames: int = 2  # consecutive detections before a track gets an id
    max_tracks: int = 256  # bounds the state: tracks beyond this (lowest-scoring new ones) are not started


class Tracker:
    """One robot's tracker: `update()` with each frame's detections, in the frames' order."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        from trackers import ByteTrackTracker

        self.config = config = config or TrackerConfig()
        self._bt = ByteTrackTracker(
            lost_track_buffer=max(0, round(config.lost_track_s * 30)),  # the library counts 30 fps frames
            frame_rate=config.frame_rate,
            track_activation_threshold=config.activation_conf,
            minimum_consecutive_frames=config.min_frames,
            minimum_iou_threshold=config.min_iou,
            high_conf_det_threshold=config.high_conf,
        )

    @property
    def track_count(self) -> int:
        return len(self._bt.tracks)

    def update(self, detections: Sequence[Any], timestamp_s: float) -> list[Any]:
        """The wire's detections (`bbox`, `score`), each with `track_id`, in the input's order (`track`)."""
        return self.track(Detections.from_wire(list(detections), strict=False), timestamp_s).to_wire()

    def track(self, detections: Detections, timestamp_s: float) -> Detections:
        """The detections with a track id each (-1 until a track is confirmed, or for a frame older than the last
        one, which the tracker skips); a detection without a score counts as sure."""
        import supervision as sv

        ids = np.full(len(detections), -1, np.int64)
        last = self._bt._last_timestamp
        if last is not None and timestamp_s <= last:
            return detections.with_tracker_id(ids)  # out of order or repeated: the filter cannot go back in time
        if len(detections):
            conf = np.nan_to_num(detections.confidence, nan=1.0).astype(np.float32)
            xyxy = detections.xyxy.astype(np.float32)
            dets = sv.Detections(xyxy=xyxy, confidence=conf, data={"index": np.arange(len(detections))})
        else:
            dets = sv.Detections.empty()
            dets.data["index"] = np.empty(0, dtype=int)
        tracked = self._bt.update(dets, timestamp=timestamp_s)
        if len(self._bt.tracks) > self.config.max_tracks:  # bound the state: confirmed and recently seen first
            ranked = sorted(self._bt.tracks, key=lambda t: (t.tracker_id < 0, t.time_since_update))
            self._bt.tracks = ranked[: self.config.max_tracks]
        for index, track_id in zip(tracked.data.get("index", []), tracked.tracker_id, strict=True):
            if track_id >= 0:
                ids[int(index)] = int(track_id)
        return detections.with_tracker_id(ids)

    def reset(self) -> None:
        self._bt.reset()

    # -- state ---------------------------------------------------------------------------------------------------

    def to_json(self) -> dict[str, Any]:
        """The whole state as JSON data (about 0.35 KB per live track)."""
        bt = self._bt
        filters = [t.state_estimator.get_state() for t in bt.tracks]
        numbers = np.zeros((len(filters), _DIM + len(_UPPER[0])))
        for row, kf in zip(numbers, filters, strict=True):
            row[:_DIM] = kf["state"].ravel()
            row[_DIM:] = kf["state_covariance"][_UPPER]
        rows = _short(numbers).tolist()  # one vectorised rounding for all tracks
        tracks = [
            [
                int(t.tracker_id),
                int(t.age),
                int(t.time_since_update),
                float(t.time_since_update_seconds),
                int(t.number_of_successful_consecutive_updates),
                row[:_DIM],
                row[_DIM:],
            ]
            for t, row in zip(bt.tracks, rows, strict=True)
        ]
        return {"v": STATE_VERSION, "next_id": int(bt._next_track_id), "t": bt._last_timestamp, "tracks": tracks}

    def load_json(self, data: Any) -> None:
        """Replace the state with `data` from `to_json()`; ValueError saying what is wrong (nothing changes then)."""
        from trackers.core.bytetrack.tracklet import ByteTrackTracklet

        next_id, last_t, rows = _validate(data, self.config.max_tracks)
        restored = []
        for track_id, age, since, since_s, consecutive, state, upper in rows:
            tracklet = ByteTrackTracklet(np.asarray(state[:4], dtype=np.float64))
            kf = tracklet.state_estimator.get_state()  # the filter's matrices as the settings make them
            kf["state"] = np.asarray(state, dtype=np.float64).reshape(_DIM, 1)
            cov = np.zeros((_DIM, _DIM))
            cov[_UPPER] = upper
            kf["state_covariance"] = cov + np.triu(cov, 1).T
            tracklet.state_estimator.set_state(kf)
            tracklet.tracker_id = track_id
            tracklet.age = age
            tracklet.time_since_update = since
            tracklet.time_since_update_seconds = since_s
            tracklet.number_of_successful_consecutive_updates = consecutive
            restored.append(tracklet)
        self._bt.tracks = restored
        self._bt._next_track_id = next_id
        self._bt._last_timestamp = last_t


def _validate(data: Any, max_tracks: int) -> tuple[int, float | None, list[list[Any]]]:
    if not isinstance(data, Mapping):
        raise ValueError(f"tracker state must be an object, got {type(data).__name__}")
    if data.get("v") != STATE_VERSION:
        raise ValueError(f"tracker state version {data.get('v')!r} is not {STATE_VERSION}")
    next_id, last_t, rows = data.get("next_id"), data.get("t"), data.get("tracks")
    if not _is_int(next_id) or next_id < 0:
        raise ValueError("tracker state: 'next_id' must be a non-negative integer")
    if last_t is not None and not _is_finite(last_t):
        raise ValueError("tracker state: 't' must be a number or null")
    if not isinstance(rows, list) or len(rows) > max_tracks:
        raise ValueError(f"tracker state: 'tracks' must be a list of at most {max_tracks} tracks")
    ids = set()
    for i, row in enumerate(rows):
        where = f"tracker state: track {i}"
        if not isinstance(row, list) or len(row) != _TRACK_FIELDS + 2:
            raise ValueError(f"{where} must be a list of {_TRACK_FIELDS + 2} fields")
        track_id, age, since, since_s, consecutive, state, upper = row
        if not _is_int(track_id) or not -1 <= track_id < next_id or (track_id >= 0 and track_id in ids):
            raise ValueError(f"{where}: id must be -1 (unconfirmed) or a unique integer below next_id")
        ids.add(track_id)
        if not all(_is_int(v) and v >= 0 for v in (age, since, consecutive)) or not _is_finite(since_s):
            raise ValueError(f"{where}: age, frames and consecutive updates must be non-negative integers")
        if not _numbers(state, _DIM) or not _numbers(upper, len(_UPPER[0])):
            raise ValueError(f"{where}: needs {_DIM} state values and {len(_UPPER[0])} covariance values, all finite")
    return next_id, (float(last_t) if last_t is not None else None), rows


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _numbers(values: Any, n: int) -> bool:
    return isinstance(values, list) and len(values) == n and all(_is_finite(v) for v in values)


def _short(values: np.ndarray) -> np.ndarray:
    """Six significant digits, vectorised: far below a pixel and the filter's own uncertainty, and half the bytes
    of full floats. Dividing by an exact power of ten leaves the shortest decimal, which JSON then writes."""
    x = np.asarray(values, dtype=np.float64)
    with np.errstate(divide="ignore"):
        k = 5 - np.floor(np.log10(np.abs(x)))
    k = np.where(np.isfinite(k), k, 0)
    up, down = 10.0 ** np.clip(k, 0, None), 10.0 ** np.clip(-k, 0, None)
    return np.round(x * up / down) * down / up
