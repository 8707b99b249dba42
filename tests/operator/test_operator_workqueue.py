"""The operator's work queue (pure asyncio): a key waits at most once, one worker at a time per key, retries."""

from __future__ import annotations

import asyncio
from collections.abc import Hashable

import pytest
from netapp_operator.workqueue import WorkQueue

pytestmark = pytest.mark.timeout(30)


async def test_a_key_waits_once_and_is_worked_again_after_an_event_during_its_work():
    """A burst of events for thousands of NetApps holds one entry per NetApp, not a backlog of events; an event
    that arrives while its NetApp is being reconciled is not lost (the worker read the state before it)."""
    calls: list[Hashable] = []
    release, done = asyncio.Event(), asyncio.Event()

    async def work(key: Hashable) -> None:
        calls.append(key)
        if key == "x" and len(calls) == 1:
            await release.wait()
        if key == "end":
            done.set()

    queue = WorkQueue(work, workers=1)
    queue.start()
    try:
        queue.add("x")
        while not calls:  # the worker has taken "x" and waits in it
            await asyncio.sleep(0)
        for _ in range(1000):
            queue.add("x")
            for key in range(100):
                queue.add(key)
        assert len(queue) == 100  # bounded by the keys, whatever the number of events
        release.set()
        while calls.count("x") < 2:
            await asyncio.sleep(0)
        queue.add("end")  # behind anything still queued: once it is done, nothing else was
        await asyncio.wait_for(done.wait(), 10)
        assert calls == ["x", *range(100), "x", "end"]
    finally:
        await queue.stop()


async def test_a_failed_key_is_tried_again():
    attempts: list[Hashable] = []
    done = asyncio.Event()

    async def work(key: Hashable) -> None:
        attempts.append(key)
        if len(attempts) == 1:
            raise RuntimeError("the API server went away")
        done.set()

    queue = WorkQueue(work, workers=2, retry_s=0.01, expected=(RuntimeError,))
    queue.start()
    try:
        queue.add(("default", "det"))
        await asyncio.wait_for(done.wait(), 10)
        assert attempts == [("default", "det")] * 2 and queue.failures == 1
    finally:
        await queue.stop()
