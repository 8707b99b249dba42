"""Every frame gets an answer, in a netapp in process: a processor that raises on some frames fails those frames
alone, and whatever escapes the batch code still answers each frame of the batch with an error."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from netapp.sdk.processor import Processor
from netapp.server.settings import Settings
from tests.netapp.server.test_hostile import post_jpeg, register
from tests.support.images import make_jpeg


class Flaky(Processor):
    """A dynamic-batch processor whose prepare raises (not a ValueError) on red frames and whose process raises
    on any batch holding a green one: everybody else's frames must still get their results."""

    name = "flaky"
    max_batch = 8

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.batches: list[int] = []

    def prepare(self, image, args):
        b, g, r = (int(v) for v in image[0, 0])
        if r > 200 and b < 60 and g < 60:
            raise RuntimeError("a processor bug on red frames")
        return "green" if g > 200 and b < 60 and r < 60 else "other"

    def process(self, batch):
        self.batches.append(len(batch))
        self.gate.wait(10)
        if "green" in batch:
            raise KeyError("a processor bug on green frames")
        return [{"kind": kind} for kind in batch]


def solid_jpeg(bgr: tuple[int, int, int]) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".jpg", np.full((16, 16, 3), bgr, np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 100])
    assert ok
    return buf.tobytes()


@pytest.mark.parametrize("prepare_threads", [0, 2], ids=["decode-on-inference-thread", "decode-pool"])
def test_every_frame_gets_an_answer_and_one_bad_frame_fails_alone(serve, prepare_threads) -> None:
    flaky = Flaky()
    url = serve(flaky, Settings(prepare_threads=prepare_threads)).url
    sessions = [register(url) for _ in range(5)]
    blocker = register(url)
    with ThreadPoolExecutor(6) as pool:
        first = pool.submit(post_jpeg, url, blocker, solid_jpeg((128, 128, 128)))
        while not flaky.batches:  # the first batch holds the inference thread: the others queue up behind it
            time.sleep(0.01)
        colours = [(0, 0, 255), (0, 255, 0), (200, 200, 200), (100, 100, 100), (50, 50, 50)]
        futures = [pool.submit(post_jpeg, url, s, solid_jpeg(c)) for s, c in zip(sessions, colours, strict=True)]
        time.sleep(0.3)  # the five frames reach their queues
        flaky.gate.set()
        replies = [f.result() for f in futures]
    assert first.result().status_code == 200
    red, green, *others = replies
    assert red.status_code == 500 and red.json()["reason"] == "prepare_failed" and "red frames" in red.text
    assert green.status_code == 500 and green.json()["reason"] == "processing_failed" and "green" in green.text
    for reply in others:
        assert reply.status_code == 200, reply.text
    assert max(flaky.batches) > 1  # the green frame was in a batch with others, which were retried alone


def test_a_batch_that_raises_unexpectedly_still_answers_its_frames(serve, monkeypatch) -> None:
    """Whatever escapes the batch code, each frame of that batch still gets an error."""
    from netapp.server.pipeline.lanes import InferenceLanes
    from tests.support.processors import GatedProcessor

    def broken(self, batch):
        raise RuntimeError("a bug in the batch code")

    monkeypatch.setattr(InferenceLanes, "run_batch", broken)
    processor = GatedProcessor()
    processor.gate.set()
    url = serve(processor).url
    reply = post_jpeg(url, register(url), make_jpeg())
    assert reply.status_code == 500 and reply.json()["reason"] == "internal_error", reply.text
