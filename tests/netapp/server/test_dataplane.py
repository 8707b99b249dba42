"""The transport-neutral dataplane, in-process: frames counted and refused inside it, sessions opened in one place,
state commands with typed errors, and observers told of results without the pipeline knowing who they are."""

from __future__ import annotations

import numpy as np
import pytest

from netapp.frame import JPEG, EncodedFrame
from netapp.sdk import Processor
from netapp.server.dataplane import DataPlane, IncomingFrame
from netapp.server.errors import FrameRejected, RequestRefused, SessionsFull
from netapp.server.http.errors import http_error
from netapp.server.services import NetAppServices
from netapp.server.settings import Settings
from tests.netapp.server.test_state import FrameCounter


class Shapes(Processor):
    name = "shapes"

    def process(self, batch):
        return [{"shape": list(image.shape)} for image in batch]


class Watching:
    """An observer that watches every session and records what it is told."""

    def __init__(self) -> None:
        self.told: list[tuple] = []

    def watched(self, session_id):
        return True

    def report(self, session, value):
        self.told.append(("report", session.id, value))

    def record(self, session, message, image):
        self.told.append(("record", session.id, message["timestamp"], None if image is None else image.shape))

    def forget(self, session_id):
        self.told.append(("forget", session_id))


def frame(timestamp: int, shape=(6, 8, 3), **meta) -> IncomingFrame:
    image = np.zeros(shape, np.uint8)
    return IncomingFrame(EncodedFrame(JPEG, timestamp, b"", meta=meta or None), lambda: image)


async def started(processor: Processor, settings: Settings | None = None) -> DataPlane:
    dataplane = DataPlane(NetAppServices.build(processor, settings or Settings(prepare_threads=0)))
    await dataplane.pipeline.start()
    return dataplane


async def parsed(incoming: IncomingFrame) -> IncomingFrame:
    return incoming


async def test_a_frame_is_counted_once_and_its_result_reaches_the_observers():
    dataplane = await started(Shapes())
    observer = Watching()
    dataplane.observe(observer)
    try:
        session = dataplane.open_session("http", "bot", {})
        accepted = await dataplane.submit(session, "http", lambda: parsed(frame(7, latency="{}")), wait=True)
        message = await dataplane.result(session, accepted)
        assert message["shape"] == [6, 8, 3] and message["timestamp"] == 7
        assert (session.received, session.processed, session.rejected) == (1, 1, 0)
        dataplane.close_session(session, "done")
        assert observer.told == [
            ("report", session.id, "{}"),
            ("record", session.id, 7, (6, 8, 3)),  # watched: the decoded frame came with the result
            ("forget", session.id),
        ]
    finally:
        await dataplane.pipeline.stop()


async def test_a_frame_the_transport_cannot_parse_is_counted_as_received_and_rejected():
    dataplane = await started(Shapes())
    try:
        session = dataplane.open_session("ws", None, {})

        async def bad() -> IncomingFrame:
            raise FrameRejected("bad_frame", "not a frame")

        with pytest.raises(FrameRejected, match="not a frame"):
            await dataplane.submit(session, "ws", bad)

        async def broken() -> IncomingFrame:
            raise KeyError("a bug in a decoder")

        with pytest.raises(FrameRejected) as caught:
            await dataplane.submit(session, "ws", broken)
        assert (caught.value.reason, caught.value.status) == ("internal_error", 500)
        assert (session.received, session.rejected, session.processed) == (2, 2, 0)
        metrics = dataplane.services.metrics.render().decode()
        assert 'reason="bad_frame",transport="ws"} 1.0' in metrics
    finally:
        await dataplane.pipeline.stop()


async def test_sessions_open_in_one_place_with_typed_errors():
    dataplane = DataPlane(NetAppServices.build(FrameCounter(), Settings(max_sessions=1)))
    with pytest.raises(RequestRefused) as bad:
        dataplane.open_session("ws", None, {"state_checkpoint_every": -1})
    assert (bad.value.status, bad.value.reason) == (422, "invalid_request")
    session = dataplane.register("bot", {"start": 3})
    assert dataplane.token_session(session.id) is session
    with pytest.raises(SessionsFull) as full:
        dataplane.open_session("ws", None, {})
    error = http_error(full.value)
    assert (error.status, error.headers, error.extra) == (503, {"Retry-After": "5"}, {"retry_after_s": 5, "limit": 1})
    assert "netapp_sessions_refused_total 1.0" in dataplane.services.metrics.render().decode()  # the chart's alerts
    dataplane.close_session(session, "bye", revoke=True)
    with pytest.raises(RequestRefused) as gone:
        dataplane.token_session(session.id)
    assert (gone.value.status, gone.value.reason, gone.value.details) == (
        404,
        "unknown_session",
        {"session_id": session.id},
    )
    dataplane.services.draining = True
    with pytest.raises(RequestRefused) as draining:
        dataplane.register("bot", {})
    assert http_error(draining.value).headers == {"Retry-After": "1"} and draining.value.status == 503


async def test_the_state_commands_run_through_the_dataplane():
    dataplane = await started(FrameCounter())
    try:
        session = dataplane.open_session("ws", "bot", {"start": 5})
        assert await dataplane.get_state(session) == '{"count":5}'
        await dataplane.set_state(session, {"count": 9})
        with pytest.raises(RequestRefused) as bad:
            await dataplane.set_state(session, {"count": "many"})
        assert (bad.value.status, bad.value.reason) == (422, "bad_state")
        assert await dataplane.get_state(session) == '{"count":9}'  # a bad state left it as it was
        await dataplane.reset_state(session)
        assert await dataplane.get_state(session) == '{"count":5}'
        with pytest.raises(RequestRefused, match="--state-dir"):
            await dataplane.save_state(session, "bot")
    finally:
        await dataplane.pipeline.stop()
    stateless = DataPlane(NetAppServices.build(Shapes(), Settings()))
    with pytest.raises(RequestRefused) as refused:
        await stateless.get_state(stateless.open_session("http", None, {}))
    assert (refused.value.status, refused.value.reason) == (409, "stateless")


async def test_a_polled_frame_is_refused_while_draining_and_a_waited_one_is_capped():
    dataplane = await started(Shapes(), Settings(prepare_threads=0, max_waiting=0))
    try:
        session = dataplane.open_session("http", None, {})
        with pytest.raises(FrameRejected) as capped:
            await dataplane.submit(session, "http", lambda: parsed(frame(1)), wait=True)
        assert capped.value.reason == "too_many_waiting" and http_error(capped.value).headers == {"Retry-After": "1"}
        dataplane.services.draining = True
        with pytest.raises(FrameRejected) as draining:
            await dataplane.submit(session, "http", lambda: parsed(frame(2)))
        assert draining.value.reason == "draining"
        assert (session.received, session.rejected) == (2, 2)
    finally:
        await dataplane.pipeline.stop()


def test_the_session_cap_counts_only_live_sessions_admitted_here():
    key = b"k" * 32

    def replica(address: str) -> DataPlane:
        settings = Settings(max_sessions=1, cluster_key=key, advertise_url=address, live_session_s=30)
        return DataPlane(NetAppServices.build(Shapes(), settings))

    a, b = replica("http://10.0.0.1:5896"), replica("http://10.0.0.2:5896")
    elsewhere = a.register("robot-a", {})
    assert b.token_session(elsewhere.id).admitted is False  # a's robot, its frames landing on b: a record here
    mine = b.register("robot-b", {})  # the record does not count against b's cap
    with pytest.raises(SessionsFull):
        b.register("robot-c", {})
    mine.last_seen -= 31  # robot-b made no request for longer than live_session_s: no longer counted
    assert b.register("robot-c", {}).admitted
    assert len(b.services.sessions) == 3  # every record kept until it expires (session_ttl_s)
