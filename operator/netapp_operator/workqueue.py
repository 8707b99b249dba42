"""The operator's own reconcile queue: watch events add keys, a few workers reconcile them (no I/O of its own).

Level-triggered: a key waits in the queue at most once however many events name it, and the worker that takes it
reads the latest state from the cache. So a burst of thousands of NetApps holds a set of keys, not a backlog of
watch events, and one NetApp is never reconciled by two workers at once (docs/operator.md#at-fleet-scale).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable, Hashable, Iterable
from typing import Any

logger = logging.getLogger(__name__)


async def cancel(tasks: Iterable[asyncio.Task[Any]]) -> None:
    """Cancel background tasks and wait for each to end."""
    tasks = list(tasks)
    for task in tasks:
        task.cancel()
    for task in tasks:
        with contextlib.suppress(asyncio.CancelledError):
            await task


class WorkQueue:
    """Keys to reconcile; `work(key)` raising is logged (an `expected` error in one line, anything else with its
    traceback) and the key is tried again after `retry_s`."""

    def __init__(
        self,
        work: Callable[[Hashable], Awaitable[None]],
        *,
        workers: int = 16,
        retry_s: float = 5.0,
        expected: tuple[type[Exception], ...] = (),
    ) -> None:
        self._work = work
        self._expected = expected
        self._workers = workers
        self._retry_s = retry_s
        self._queue: asyncio.Queue[Hashable] = asyncio.Queue()
        self._queued: set[Hashable] = set()
        self._active: set[Hashable] = set()
        self._again: set[Hashable] = set()  # added while being worked on: once more afterwards
        self._tasks: list[asyncio.Task[None]] = []
        self.failures = 0  # work that raised (each retried)
        self.completed = 0  # work that returned (the operator's /metrics counts both)

    def __len__(self) -> int:
        return len(self._queued)

    def add(self, key: Hashable) -> None:
        if key in self._queued:
            return
        if key in self._active:
            self._again.add(key)
            return
        self._queued.add(key)
        self._queue.put_nowait(key)

    def start(self) -> None:
        self._tasks = [
            asyncio.create_task(self._worker(), name=f"netapp-operator-worker-{i}") for i in range(self._workers)
        ]

    async def stop(self) -> None:
        await cancel(self._tasks)
        self._tasks = []

    async def _worker(self) -> None:
        while True:
            key = await self._queue.get()
            self._queued.discard(key)
            self._active.add(key)
            try:
                await self._work(key)
                self.completed += 1
            except Exception as e:
                self.failures += 1
                logger.warning(
                    "reconciling %s failed, again in %.0f s: %s",
                    key,
                    self._retry_s,
                    e,
                    exc_info=not isinstance(e, self._expected),
                )
                asyncio.get_running_loop().call_later(self._retry_s, self.add, key)
            finally:
                self._active.discard(key)
                if key in self._again:
                    self._again.discard(key)
                    self.add(key)
