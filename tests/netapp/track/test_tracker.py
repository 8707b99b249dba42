"""The tracker and the SDK's state contract, without a server: ids are stable, and a state saved as JSON and
restored elsewhere continues where it was (the same ids on the same objects)."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from netapp.models.detector import DetectorConfig
from netapp.sdk.session_state import StateError, dump_state, load_state
from netapp.track.processor import TrackingDetector
from netapp.track.tracker import Tracker, TrackerConfig

FPS = 25


def walkers(frames: int, count: int = 5, seed: int = 1) -> list[list[dict]]:
    """Boxes of `count` objects crossing the image at their own speeds, with detection jitter and misses."""
    rng = np.random.default_rng(seed)
    start = rng.uniform([0, 100], [400, 400], size=(count, 2))
    speed = rng.uniform(-4, 4, size=(count, 2))
    out = []
    for f in range(frames):
        dets = []
        for k in range(count):
            if rng.random() < 0.05:
                continue  # a missed detection now and then
            x, y = start[k] + speed[k] * f + rng.normal(0, 0.7, 2)
            dets.append({"bbox": [x, y, x + 40, y + 90], "score": float(rng.uniform(0.55, 0.95)), "object": k})
        out.append(dets)
    return out


def run(tracker: Tracker, frames: list[list[dict]], first: int = 0) -> list[list[tuple[int, int | None]]]:
    return [
        [(d["object"], d["track_id"]) for d in tracker.update(dets, (first + i) / FPS)] for i, dets in enumerate(frames)
    ]


def test_each_object_keeps_one_id():
    out = run(Tracker(), walkers(120))
    ids: dict[int, set[int]] = {}
    for frame in out[5:]:
        for obj, track_id in frame:
            ids.setdefault(obj, set()).add(track_id)
    assert all(len(v) == 1 and None not in v for v in ids.values()), ids
    assert len({next(iter(v)) for v in ids.values()}) == len(ids)  # and no two objects share one


def test_a_restored_tracker_continues_exactly():
    frames = walkers(150)
    reference = Tracker()
    expected = run(reference, frames)
    first = Tracker()
    run(first, frames[:70])
    text = json.dumps(first.to_json())
    second = Tracker()
    second.load_json(json.loads(text))
    assert run(second, frames[70:], first=70) == expected[70:]
    assert second.to_json()["next_id"] == reference.to_json()["next_id"]


def test_a_restore_across_a_gap_keeps_ids():
    """The frames between the checkpoint and the move are lost: the filter predicts across the gap."""
    frames = walkers(150)
    expected = run(Tracker(), frames)
    first = Tracker()
    run(first, frames[:60])
    second = Tracker()
    second.load_json(first.to_json())
    after = run(second, frames[70:], first=70)
    assert after[5:] == expected[75:]


def bad_states():
    good = Tracker()
    run(good, walkers(20))
    state = good.to_json()
    assert state["tracks"]

    def changed(fn):
        s = copy.deepcopy(state)
        fn(s)
        return s

    return [
        ([], "must be an object"),
        (changed(lambda s: s.update(v=99)), "version"),
        (changed(lambda s: s.update(next_id=-1)), "next_id"),
        (changed(lambda s: s.update(t="later")), "'t'"),
        (changed(lambda s: s.update(tracks={})), "list of at most"),
        (changed(lambda s: s.update(tracks=s["tracks"] * 200)), "list of at most"),
        (changed(lambda s: s["tracks"][0].pop()), "fields"),
        (changed(lambda s: s["tracks"][0].__setitem__(0, s["next_id"])), "below next_id"),
        (changed(lambda s: s["tracks"].append(copy.deepcopy(s["tracks"][0]))), "unique"),
        (changed(lambda s: s["tracks"][0].__setitem__(1, -3)), "non-negative"),
        (changed(lambda s: s["tracks"][0][5].__setitem__(0, float("nan"))), "finite"),
        (changed(lambda s: s["tracks"][0].__setitem__(6, [1.0])), "covariance"),
    ]


@pytest.mark.parametrize("state, message", bad_states())
def test_a_bad_state_is_refused_and_changes_nothing(state, message):
    tracker = Tracker()
    run(tracker, walkers(10))
    before = tracker.to_json()
    with pytest.raises(ValueError, match=message):
        tracker.load_json(state)
    assert tracker.to_json() == before


def test_the_number_of_tracks_is_bounded():
    tracker = Tracker(TrackerConfig(max_tracks=3))
    run(tracker, walkers(10, count=8))
    assert tracker.track_count <= 3
    assert len(tracker.to_json()["tracks"]) <= 3


def test_an_older_frame_gets_no_ids_and_changes_nothing():
    tracker = Tracker()
    frames = walkers(10)
    run(tracker, frames)
    before = tracker.to_json()
    out = tracker.update(frames[3], 3 / FPS)
    assert [d["track_id"] for d in out] == [None] * len(out)
    assert tracker.to_json() == before


def test_state_text_is_bounded_both_ways():
    processor = TrackingDetector(DetectorConfig("unused.onnx"))  # never loaded: the state needs no model
    state = processor.new_state({})
    run(state, walkers(30))
    text = dump_state(processor, state)
    assert len(text) < 5 * 1024  # five tracks
    restored = load_state(processor, text)
    assert restored.to_json() == state.to_json()
    assert load_state(processor, json.loads(text)).to_json() == state.to_json()  # SET_STATE's `data` object
    processor.max_state_bytes = 100
    with pytest.raises(StateError, match="over the 100-byte limit"):
        dump_state(processor, state)
    with pytest.raises(StateError, match="over the 100-byte limit"):
        load_state(processor, text)
    with pytest.raises(StateError, match="over the 100-byte limit"):
        load_state(processor, json.loads(text))
    processor.max_state_bytes = 1 << 20
    with pytest.raises(StateError, match="not valid JSON"):
        load_state(processor, "{")
    with pytest.raises(StateError, match="cannot restore this state: tracker state must be an object"):
        load_state(processor, "[1]")


def test_compare_counts_id_switches_by_position():
    from netapp.track.compare import id_switches, matched_ids

    a = {"bbox": [0, 0, 10, 10], "track_id": 1}
    b = {"bbox": [50, 0, 60, 10], "track_id": 2}
    moved = {"bbox": [1, 0, 11, 10], "track_id": 1}
    assert id_switches([[a, b], [moved, b], [{**moved, "track_id": 7}, b], [{**moved, "track_id": None}]]) == 1
    unconfirmed = {**moved, "track_id": None}
    assert id_switches([[a], [unconfirmed], [unconfirmed], [{**moved, "track_id": 3}]]) == 1  # seen through Nones
    assert id_switches([[a]] + [[]] * 5 + [[{**moved, "track_id": 3}]]) == 0  # too long ago: a new object
    assert matched_ids([a, b], [{**b, "track_id": 5}, moved], min_iou=0.7) == [(2, 5), (1, 1)]
