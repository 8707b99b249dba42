"""Real detection through the whole netapp: the shared YOLOX-Nano, dog.jpg and the pedestrian video."""

from __future__ import annotations

import itertools

import cv2
import pytest

from netapp.client import NetAppClient
from netapp.client.sources import open_source
from netapp.models import Detector, DetectorConfig


@pytest.fixture(scope="module")
def real_server(real_model_path):
    from netapp.server.app import create_app
    from tests.support.servers import BackgroundServer

    with BackgroundServer(create_app(Detector(DetectorConfig(str(real_model_path))))) as server:
        yield server


@pytest.mark.parametrize("transport", ["http", "ws"])
def test_dog_bicycle_and_car_over_the_network(real_server, media_dir, transport):
    jpeg = (media_dir / "dog.jpg").read_bytes()
    with NetAppClient(real_server.url, transport=transport) as client:
        client.send(jpeg)
        assert client.wait_idle(60)
        (result,) = list(client.results(timeout=1))
    names = {d["class_name"] for d in result.detections if d["score"] >= 0.75}
    assert {"dog", "bicycle", "car"} <= names
    image = cv2.imread(str(media_dir / "dog.jpg"))
    for d in result.detections:  # boxes are in the original image's pixels
        x1, y1, x2, y2 = d["bbox"]
        assert 0 <= x1 < x2 <= image.shape[1] and 0 <= y1 < y2 <= image.shape[0]


def test_people_in_the_pedestrian_video(real_server, media_dir):
    frames = itertools.islice(open_source(str(media_dir / "pedestrians.avi"), 10, (640, 480)), 5)
    with NetAppClient(real_server.url, transport="ws", max_in_flight=1) as client:
        for frame in frames:
            client.send(frame)
            assert client.wait_idle(60)
        results = list(client.results(timeout=1))
    assert len(results) == 5
    people = [sum(d["class_name"] == "person" for d in r.detections) for r in results]
    assert min(people) >= 5, people  # about 15-20 people walk across the hall
