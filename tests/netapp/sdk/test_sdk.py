"""The SDK: any Processor becomes a netapp with every transport; frames from several robots share a batch."""

from __future__ import annotations

import threading

import numpy as np
import requests

from netapp.client import NetAppClient
from netapp.sdk import Processor
from tests.support.images import make_jpeg
from tests.support.processors import GatedProcessor


class MeanColour(Processor):
    name = "mean-colour"

    def prepare(self, image, args):
        return image.reshape(-1, 3).mean(axis=0)

    def process(self, batch):
        return [{"mean_bgr": [round(float(v)) for v in mean]} for mean in batch]


def test_a_custom_processor_served_over_both_transports(serve):
    server = serve(MeanColour())
    for transport in ("http", "ws"):
        with NetAppClient(server.url, transport=transport) as client:
            client.send(np.full((48, 64, 3), (10, 200, 90), np.uint8))
            assert client.wait_idle(20)
            (result,) = list(client.results(timeout=0.5))
        assert result.detections == []
        assert np.allclose(result.message["mean_bgr"], [10, 200, 90], atol=4)  # JPEG rounding
    assert requests.get(f"{server.url}/v2/models/mean-colour", timeout=5).json()["name"] == "mean-colour"


def test_frames_from_several_robots_are_batched(serve):
    class Batched(GatedProcessor):
        max_batch = 4
        sizes: list[int] = []

        def process(self, batch):
            self.sizes.append(len(batch))
            return super().process(batch)

    processor = Batched()
    server = serve(processor)
    clients = [NetAppClient(server.url, transport="ws", max_in_flight=1).connect() for _ in range(4)]
    try:
        clients[0].send(make_jpeg())
        assert processor.entered.acquire(timeout=10)  # robot 0's frame holds the inference thread
        for c in clients[1:]:
            c.send(make_jpeg())
        depth = "netapp_queue_depth 3.0"
        deadline = threading.Event()
        for _ in range(500):
            if depth in requests.get(f"{server.url}/metrics", timeout=5).text:
                break
            deadline.wait(0.02)
        processor.gate.set()
        for c in clients:
            assert c.wait_idle(20) and c.stats.results == 1
    finally:
        for c in clients:
            c.close()
    assert processor.sizes == [1, 3]  # the three waiting robots went through in one inference
