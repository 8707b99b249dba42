"""The one detections type (netapp/detections.py): the wire's result read once into columns and written back
unchanged, bad input refused with a message that names the detection and the field (or set aside, leniently),
selection by a mask, scaling to the source's pixels, and the columns the readers draw from."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from netapp.detections import Detections, as_detections
from netapp.results import MAX_DETECTIONS, mask_to_array, rbox_corners
from tests.support.result_processors import HOSTILE_FIELDS, scene


def wire(message: dict) -> dict:
    """The message as a robot receives it: through JSON."""
    return json.loads(json.dumps(message))


def test_a_scene_reads_into_columns_and_goes_back_unchanged():
    message = wire({"timestamp": 7, "hint": {"x": 1}, **scene(640, 480)})
    before = copy.deepcopy(message)
    dets = Detections.from_wire(message)
    assert len(dets) == 2 and dets.to_wire() == message and message == before
    assert dets.xyxy.shape == (2, 4) and dets.xyxy.dtype == np.float64
    assert dets.class_id.tolist() == [0, 16] and dets.class_name.tolist() == ["person", "dog"]
    assert dets.confidence.tolist() == [0.9, 0.8]
    assert dets.keypoints.shape == (2, 17, 3) and dets.has_keypoints().tolist() == [True, False]
    assert dets.has_rbox().tolist() == [True, False] and dets.has_rle()
    assert dets.tracker_id is None
    # the oriented box's corners, as the field-level helper gives them
    np.testing.assert_allclose(dets.rbox_corners()[0], rbox_corners(message["detections"][0]["rbox"]))
    assert np.isnan(dets.rbox_corners()[1]).all()
    # masks stay as the wire has them and decode on request
    assert dets.masks[0] == message["detections"][0]["mask"]
    dog = dets.mask_array(1, 480, 640)
    assert (dog == mask_to_array(message["detections"][1]["mask"], 480, 640)).all()
    assert dets.label(0) == "person 0.90"
    assert Detections.from_wire(message["detections"]).to_wire() == message["detections"]  # a list gives a list


def test_a_tracked_result_and_a_custom_processors_fields_round_trip():
    detections = [
        {"bbox": [1, 2, 3, 4], "score": 0.5, "class": 2, "class_name": "car", "track_id": 3, "depth_m": 4.2},
        {"bbox": [5, 6, 7, 8], "score": 0.25, "class": 2, "class_name": "car", "track_id": None},
    ]
    dets = Detections.from_wire(detections)
    assert dets.tracker_id.tolist() == [3, -1] and dets.data[0] == {"depth_m": 4.2}
    assert dets.to_wire() == detections
    assert Detections.from_wire({"detections": [], "classifications": [{"class": 1}]}).to_wire() == {
        "detections": [],
        "classifications": [{"class": 1}],
    }


def test_every_real_exports_result_round_trips(media_dir):
    """What the netapp sends today for each real export (every task, both mask forms), through JSON."""
    from netapp.models import Detector, DetectorConfig
    from tests.support.exports import IMAGES, MODELS, REFERENCE_ARGS, export_path, robot_frame

    for model in MODELS:
        for mask_format in ("polygons", "rle") if model.endswith("-seg") else ("polygons",):
            detector = Detector(DetectorConfig(str(export_path(model)), mask_format=mask_format, **REFERENCE_ARGS))
            detector.load()
            for image in IMAGES:
                _, frame = robot_frame(media_dir, image)
                message = wire(detector.process([detector.prepare(frame, {})])[0])
                dets = Detections.from_wire(message)  # strict: every field valid
                assert dets.to_wire() == message, (model, mask_format, image)
                assert len(dets) == len(message["detections"])


@pytest.mark.parametrize(
    ("bad", "words"),
    [
        ("junk", "a result's detections must be a list"),
        (["junk"], "detection 0: must be an object"),
        ([{"bbox": [0, 0, 1]}], "detection 0: 'bbox' must be [x1, y1, x2, y2]"),
        ([{"bbox": [0, 0, 1, float("inf")]}], "'bbox' must be"),
        ([{"bbox": [0, 0, 1, True]}], "'bbox' must be"),
        ([{"bbox": [0, 0, 1, 1], "score": float("nan")}], "'score' must be a finite number"),
        ([{"bbox": [0, 0, 1, 1], "class": "x"}], "'class' must be a non-negative integer"),
        ([{"bbox": [0, 0, 1, 1], "class_name": "x" * 300}], "'class_name' must be a string"),
        ([{"bbox": [0, 0, 1, 1], "track_id": -4}], "'track_id' must be"),
        ([{"bbox": [0, 0, 1, 1], "keypoints": []}], "'keypoints' must not be empty"),
        (
            [{"bbox": [0, 0, 1, 1], "keypoints": [[1, 1, 1]] * 2}, {"bbox": [0, 0, 1, 1], "keypoints": [[1, 1, 1]]}],
            "detection 1: has 1 keypoints where the others have 2",
        ),
        (
            [{"bbox": [0, 0, 1, 1], "track_id": 1}, {"bbox": [0, 0, 1, 1]}],
            "a tracked result gives every detection a 'track_id'",
        ),
        ([{"bbox": [0, 0, 1, 1]}] * (MAX_DETECTIONS + 1), f"{MAX_DETECTIONS} detections at most"),
    ]
    + [([{"bbox": [1, 1, 9, 9], name: value}], f"'{name}'") for name, value, _ in HOSTILE_FIELDS],
)
def test_bad_input_is_refused_with_a_clear_message(bad, words):
    with pytest.raises(ValueError, match=None) as refused:
        Detections.from_wire(bad)
    assert words in str(refused.value)


def test_leniently_what_is_malformed_is_set_aside_and_still_goes_back_as_it_came():
    hostile = [{"bbox": [1, 1, 9, 9], "class": 1, name: value} for name, value, _ in HOSTILE_FIELDS]
    message = {"detections": ["junk", {"bbox": [1, 2]}, *hostile, {"bbox": [0, 0, 2, 2], "class": "x"}], "t": 1}
    dets = Detections.from_wire(message, strict=False)
    assert len(dets) == len(hostile) + 1  # every good box, none of its bad fields
    assert not dets.has_mask().any() and not dets.has_keypoints().any() and not dets.has_rbox().any()
    assert dets.class_id.tolist() == [1] * len(hostile) + [-1]
    assert dets.to_wire() == message
    assert dets.wire_places().tolist() == list(range(2, len(message["detections"])))  # where each one stood
    assert len(Detections.from_wire({"detections": "junk"}, strict=False)) == 0
    assert as_detections(message).to_wire() == message


def test_selection_by_a_mask_and_by_indices():
    dets = Detections.from_wire(wire(scene(640, 480)))
    sure = dets[dets.confidence > 0.85]
    assert len(sure) == 1 and sure.class_name.tolist() == ["person"] and sure.has_rbox().tolist() == [True]
    dog = dets[1]
    assert len(dog) == 1 and dog.to_wire() == [scene(640, 480)["detections"][1]]
    assert len(dets[dets.class_id == 99]) == 0 and dets[dets.class_id == 99].to_wire() == []
    both = Detections.merge([dog, sure])
    assert both.class_name.tolist() == ["dog", "person"] and both.has_keypoints().tolist() == [False, True]


def test_scaling_to_the_source_takes_every_coordinate_and_keeps_the_rest():
    small, large = wire(scene(320, 240)), wire(scene(640, 480))
    back = Detections.from_wire(small).scaled(2.0, 2.0).to_wire()
    person, dog = back["detections"]
    expected = large["detections"][0]
    assert person["bbox"] == pytest.approx(expected["bbox"], abs=0.1)
    assert person["mask"]["polygons"][0] == pytest.approx(expected["mask"]["polygons"][0], abs=0.1)
    np.testing.assert_allclose(person["keypoints"], expected["keypoints"], atol=0.11)
    assert person["rbox"][:4] == pytest.approx(expected["rbox"][:4], abs=0.1) and person["rbox"][4] == 0.5
    assert dog["mask"] == small["detections"][1]["mask"]  # an RLE stays at the size it was found at
    assert back["classifications"] == small["classifications"]


def test_pose_gives_the_sure_keypoints_and_the_limbs_between_them():
    from tests.support.result_processors import UNSURE_KEYPOINT

    dets = Detections.from_wire(wire(scene(640, 480)))
    points, limbs = dets.pose(0)
    assert len(points) == 16 and limbs  # the unsure one is left out, and the limbs that end at it
    assert tuple(dets.keypoints[0, UNSURE_KEYPOINT, :2]) not in points
    assert dets.pose(1) == ([], [])


def test_a_decoded_mask_may_be_handed_in_and_goes_back_exact():
    mask = np.zeros((20, 30), bool)
    mask[5:10, 3:12] = True
    dets = Detections.from_wire([{"bbox": [3, 5, 12, 10], "class": 0, "mask": mask}])
    assert dets.mask_array(0, 20, 30) is mask
    assert (mask_to_array(dets.to_wire()[0]["mask"], 20, 30) == mask).all()


def test_an_rles_runs_are_checked_where_it_is_decoded_when_read_leniently():
    bad_runs = [{"bbox": [0, 0, 4, 4], "mask": {"rle": {"size": [4, 4], "counts": "0"}}}]  # runs add up to 0, not 16
    with pytest.raises(ValueError, match="'mask'"):
        Detections.from_wire(bad_runs)
    lenient = Detections.from_wire(bad_runs, strict=False)
    assert lenient.has_mask().tolist() == [True] and lenient.mask_array(0, 4, 4) is None
    assert lenient.mask_outlines(0, 4, 4) == [] and lenient.to_wire() == bad_runs
