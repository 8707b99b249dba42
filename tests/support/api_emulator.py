"""The Kubernetes API emulator served on loopback from a thread of its own, for netapps in other threads or
processes (camera Leases): tests and benchmarks. Needs kmock (the `test` extra)."""

from __future__ import annotations

import asyncio
import threading

import requests


class ApiEmulator:
    """The Kubernetes API emulator (kmock, tests/support/kube_emulator.py) on its own event loop in a thread, so netapps
    in other threads can use it."""

    def __enter__(self) -> ApiEmulator:
        import kmock

        from tests.support.kube_emulator import Emulator, declare

        ready = threading.Event()

        async def main() -> None:
            self.stop = asyncio.Event()
            async with Emulator() as emulator, kmock.Server(emulator):
                declare(emulator)
                self.url = str(emulator.url).rstrip("/")
                ready.set()
                await self.stop.wait()

        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_until_complete, args=(main(),), daemon=True)
        self.thread.start()
        assert ready.wait(30), "the emulator did not start"
        return self

    def lease(self, namespace: str, name: str) -> dict | None:
        answer = requests.get(f"{self.url}/apis/coordination.k8s.io/v1/namespaces/{namespace}/leases/{name}", timeout=5)
        return answer.json() if answer.status_code == 200 else None

    def __exit__(self, *exc) -> None:
        self.loop.call_soon_threadsafe(self.stop.set)
        self.thread.join(timeout=10)
