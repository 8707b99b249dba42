"""The unmodified era-5g-client still gets its boxes, classes and scores from a netapp whose results carry masks,
keypoints, oriented boxes and classifications (extra keys it passes through untouched)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from tests.support.era_robot import era_robot
from tests.support.result_processors import SceneProcessor, person_box


def test_unmodified_era_5g_client_gets_boxes_from_a_netapp_with_masks(serve):
    server = serve(SceneProcessor())
    with era_robot(server.url, robot="era") as (client, got):
        from era_5g_interface.channels import ChannelType

        frame = np.full((120, 160, 3), 90, np.uint8)
        for _ in range(3):
            ts = time.perf_counter_ns()
            client.send_image(frame, "image", ChannelType.JPEG, ts)
            result = got.get(timeout=10)
            assert result["timestamp"] == ts
            person, dog = result["detections"]
            assert (person["class_name"], person["class"], person["score"]) == ("person", 0, 0.9)
            assert person["bbox"] == pytest.approx(person_box(160, 120), abs=0.1)  # the schema it knows
            assert (dog["class_name"], dog["score"]) == ("dog", 0.8)
            assert "polygons" in person["mask"] and "rle" in dog["mask"] and len(person["keypoints"]) == 17
            assert result["classifications"][0]["class_name"] == "golden retriever"
