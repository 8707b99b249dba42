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


class Named(Processor):
    """Answers each frame with its own name; fails every frame when `fails`."""

    def __init__(self, name: str, fails: bool = False) -> None:
        self.name, self.fails = name, fails

    def process(self, batch):
        if self.fails:
            raise RuntimeError(f"{self.name} failed")
        return [{"by": self.name} for _ in batch]


class RecordingHook:
    """An InferenceHook that is no rollout: it answers robot `b` with its own processor and records what it is told."""

    def __init__(self, own: Processor) -> None:
        self.own = own
        self.kept: list[tuple[int, ...]] = []
        self.batches: list[list[str]] = []
        self.failures: list[str] = []
        self.stopped = False

    def keep_image(self, frame, image) -> None:
        self.kept.append(image.shape)

    def processor_for(self, session):
        return self.own if session.id == "b" else None

    def processor_failed(self, error: str) -> None:
        self.failures.append(error)

    def after_batch(self, batch, outputs, before_ns, after_ns) -> None:
        assert after_ns >= before_ns
        self.batches.append([session.id for session, _ in batch])

    def stop(self) -> None:
        self.stopped = True


class Answers:
    """A sink that keeps each session's result or error."""

    def __init__(self) -> None:
        self.got: dict[str, object] = {}

    async def result(self, session, message):
        self.got[session.id] = message["by"]

    async def error(self, session, timestamp, error):
        self.got[session.id] = error


async def test_a_hook_rides_along_the_inference_path():
    """The pipeline knows its hook by the protocol alone (netapp/server/pipeline/hooks.py): it shows the hook each
    decoded picture, lets it answer a session with its own processor, tells it of that processor's failures and
    shows it each batch after its results have gone; stopping the pipeline stops it."""
    for own, answer_b in ((Named("hook's"), "hook's"), (Named("broken", fails=True), None)):
        sessions = SessionRegistry(results_buffer=10)
        pipeline = Pipeline(Named("served"), Settings(prepare_threads=0, lanes=1), Metrics(), sessions)
        hook = RecordingHook(own)
        pipeline.attach(hook)
        await pipeline.start()
        try:
            sink = Answers()
            image = np.zeros((6, 8, 3), np.uint8)
            for i, name in enumerate(("a", "b")):
                robot = sessions.create("ws", session_id=name)
                seq = pipeline.admit(robot, "ws")
                await pipeline.receive(robot, "ws", seq, i, lambda image=image: image, sink=sink)
            for _ in range(500):  # poll with a deadline
                if len(sink.got) == 2 and sum(map(len, hook.batches)) == 2:
                    break
                await asyncio.sleep(0.01)
            assert sink.got["a"] == "served" and hook.kept == [(6, 8, 3)] * 2
            assert sorted(s for batch in hook.batches for s in batch) == ["a", "b"]
            if answer_b is not None:
                assert sink.got["b"] == answer_b and hook.failures == []
            else:
                assert sink.got["b"] != "served" and len(hook.failures) == 1 and "broken failed" in hook.failures[0]
        finally:
            await pipeline.stop()
        assert hook.stopped
