"""What a robot gets of masks, keypoints, oriented boxes and classifications: `Result.masks(h, w)` as boolean arrays
of its own frame, `Result.keypoints()`, `Result.classifications`, all in the robot's frame pixels even when the frame
went smaller (a real netapp serving a custom processor, over each transport)."""

from __future__ import annotations

import numpy as np
import pytest

from netapp.client import NetAppClient
from netapp.client.delivery import Result
from netapp.client.sizing import to_source_coordinates
from tests.support.result_processors import SceneProcessor, dog_mask, person_box, person_keypoints, scene

WIDTH, HEIGHT = 640, 480


class HalfSizeScene(SceneProcessor):
    """Consumes frames fitted inside 320x240: the robot sends half its size and scales the fields back."""

    input_size = (320, 240)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


@pytest.mark.parametrize("transport", ["http", "ws", "frames"])
def test_a_robot_gets_masks_keypoints_and_classes_in_its_own_frame(serve, transport):
    server = serve(HalfSizeScene())
    frame = np.full((HEIGHT, WIDTH, 3), 90, np.uint8)
    with NetAppClient(server.url, transport=transport) as client:
        client.send(frame)
        result = next(client.results(timeout=20))
    assert result.message["detections"] is result.detections
    person, dog = result.detections
    assert person["bbox"] == pytest.approx(person_box(WIDTH, HEIGHT), abs=1.5)  # sent at 320x240, back at 640x480
    assert [c["class_name"] for c in result.classifications] == ["golden retriever", "labrador", "tench"]

    person_mask, dog_array = result.masks(HEIGHT, WIDTH)
    assert person_mask.shape == dog_array.shape == (HEIGHT, WIDTH) and person_mask.dtype == bool
    x1, y1, x2, y2 = person_box(WIDTH, HEIGHT)
    assert person_mask[int((y1 + y2) / 2), int((x1 + x2) / 2)] and not person_mask[int(y1) + 3, int(x1) + 3]
    assert iou(dog_array, dog_mask(WIDTH, HEIGHT)) > 0.95  # an RLE found at 320x240, resized to the robot's frame

    keypoints, none = result.keypoints()
    assert none is None and keypoints.shape == (17, 3)
    np.testing.assert_allclose(keypoints[:, :2], np.asarray(person_keypoints(WIDTH, HEIGHT))[:, :2], atol=1.5)
    cx, cy, w, h, angle = person["rbox"]
    assert (cx, cy) == pytest.approx(((x1 + x2) / 2, (y1 + y2) / 2), abs=1.5) and angle == 0.5
    assert dog["mask"]["rle"]["size"] == [240, 320]  # an RLE stays as it was found


def test_fields_scale_back_only_when_well_formed():
    detections = scene(320, 240)["detections"]
    bad = {"bbox": [0, 0, 10, 10], "mask": {"polygons": [[1, 2, 3]]}, "keypoints": [[1, "x", 1]], "rbox": [1, 2]}
    message = {"detections": [*detections, bad]}
    back = to_source_coordinates(message, (320, 240), (640, 480))
    person, _, refused = back["detections"]
    assert person["mask"]["polygons"][0] == [2 * v for v in detections[0]["mask"]["polygons"][0]]
    assert person["keypoints"][0] == [2 * detections[0]["keypoints"][0][0], 2 * detections[0]["keypoints"][0][1], 0.9]
    assert refused == {**bad, "bbox": [0, 0, 20, 20]}  # left as they came, for masks() and drawing to refuse


def test_malformed_fields_give_none_and_never_raise():
    detections = [
        {"bbox": [0, 0, 4, 4], "mask": {"rle": {"size": [4, 4], "counts": "!!!!"}}},
        {"bbox": [0, 0, 4, 4], "mask": {"rle": {"size": [4, 4], "counts": "0"}}},  # runs add up to 0, not 16
        {"bbox": [0, 0, 4, 4], "mask": {"polygons": "x"}, "keypoints": [[1, 2]]},
        "not a detection",
    ]
    result = Result(1, detections, 1.0, {"detections": detections, "classifications": "x"})
    assert result.masks(4, 4) == [None] * 4 and result.keypoints() == [None] * 4 and result.classifications == []
