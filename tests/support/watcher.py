"""A subscriber of a netapp's camera in a thread (`netapp.client.watch.Subscription`), keeping what it got: for tests
and benchmarks."""

from __future__ import annotations

import threading
import time
from typing import Any

from netapp.client.errors import NetAppError
from netapp.client.watch import Subscription


class Watcher:
    """with Watcher(url, "cam") as watcher: ... watcher.got is [(time.monotonic(), result), ...]."""

    def __init__(self, url: str, source: str, token: str | None = None) -> None:
        self.subscription = Subscription(url, source, token)
        self.got: list[tuple[float, dict[str, Any]]] = []
        self.error: NetAppError | None = None
        self._thread = threading.Thread(target=self._run, name=f"watch-{source}", daemon=True)

    def _run(self) -> None:
        try:
            for result in self.subscription.results():
                self.got.append((time.monotonic(), result))
        except NetAppError as exc:
            self.error = exc

    def count(self) -> int:
        return len(self.got)

    def since(self, t: float) -> list[tuple[float, dict[str, Any]]]:
        return [(at, r) for at, r in list(self.got) if at >= t]

    def __enter__(self) -> Watcher:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.subscription.close()
        self._thread.join(timeout=10)
