"""The pipeline's inference loop, in-process: the next batch runs while the previous results are being sent (one
lane), and several lanes run batches at once (a stateless processor only)."""

from __future__ import annotations

import asyncio
import threading

import numpy as np

from netapp.sdk import Processor
from netapp.server.metrics import Metrics
from netapp.server.pipeline.pipeline import Pipeline
from netapp.server.sessions import SessionRegistry
from netapp.server.settings import Settings


class Counting(Processor):
    name = "counting"

    def __init__(self) -> None:
        self.calls = 0
        self.second = threading.Event()

    def process(self, batch):
        self.calls += 1
        if self.calls == 2:
            self.second.set()
        return [{"call": self.calls} for _ in batch]


class HeldSink:
    """Holds the first result until released; records what it was sent, in order."""

    def __init__(self) -> None:
        self.release = asyncio.Event()
        self.sent: list[tuple[str, int]] = []

    async def result(self, session, message):
        if not self.sent:
            await self.release.wait()
        self.sent.append((session.id, message["call"]))

    async def error(self, session, timestamp, error):
        raise AssertionError(f"unexpected error {error}")


async def test_the_next_batch_runs_while_results_are_sent():
    processor = Counting()
    sessions = SessionRegistry(results_buffer=10)
    pipeline = Pipeline(processor, Settings(prepare_threads=0, lanes=1), Metrics(), sessions)
    await pipeline.start()
    try:
        sink = HeldSink()
        robots = [sessions.create("ws", session_id=f"r{i}") for i in range(2)]
        image = np.zeros((8, 8, 3), np.uint8)
        for i, robot in enumerate(robots):
            seq = pipeline.admit(robot, "ws")
            await pipeline.receive(robot, "ws", seq, i, lambda: image, sink=sink)
        # the first result is held in the sink; the second robot's frame is processed meanwhile
        assert await asyncio.to_thread(processor.second.wait, 10)
        assert sink.sent == []
        sink.release.set()
        for _ in range(500):  # poll with a deadline
            if len(sink.sent) == 2:
                break
            await asyncio.sleep(0.01)
        assert sink.sent == [("r0", 1), ("r1", 2)]
    finally:
        await pipeline.stop()


class Meeting(Processor):
    """Each batch waits, up to 10 s, until `expected` batches are in process() at once."""

    name = "meeting"

    def __init__(self, expected: int) -> None:
        self.barrier = threading.Barrier(expected, timeout=10)
        self.met = 0

    def process(self, batch):
        self.barrier.wait()  # raises BrokenBarrierError if the other batch never comes
        self.met += 1
        return [{"met": True} for _ in batch]


class CollectingSink:
    def __init__(self) -> None:
        self.results: list[dict] = []
        self.errors: list[str] = []

    async def result(self, session, message):
        self.results.append(message)

    async def error(self, session, timestamp, error):
        self.errors.append(str(error))


async def test_two_lanes_run_two_robots_batches_at_once_and_share_the_measured_cost():
    processor = Meeting(expected=2)
    sessions = SessionRegistry(results_buffer=10)
    pipeline = Pipeline(processor, Settings(prepare_threads=0, lanes=2), Metrics(), sessions)
    await pipeline.start()
    try:
        sink = CollectingSink()
        image = np.zeros((8, 8, 3), np.uint8)
        for i in range(2):
            robot = sessions.create("ws", session_id=f"r{i}")
            await pipeline.receive(robot, "ws", pipeline.admit(robot, "ws"), i, lambda: image, sink=sink)
        for _ in range(1000):  # poll with a deadline
            if len(sink.results) + len(sink.errors) == 2:
                break
            await asyncio.sleep(0.01)
        assert sink.errors == [] and len(sink.results) == 2 and processor.met == 2  # one lane would break the barrier
        # Each batch took as long as the other (they met): the netapp's cost of a result is its share of that time.
        assert pipeline.capacity.capacity_fps() is not None
    finally:
        await pipeline.stop()


def test_a_stateful_processor_has_one_lane():
    from tests.netapp.server.test_state import FrameCounter

    stateless = Pipeline(Counting(), Settings(lanes=3), Metrics(), SessionRegistry(results_buffer=10))
    stateful = Pipeline(FrameCounter(), Settings(lanes=3), Metrics(), SessionRegistry(results_buffer=10))
    assert (stateless.lanes, stateful.lanes) == (3, 1)  # its states are updated in each session's frame order
