"""Helpers shared by the middleware tests (imported by conftest.py and the test modules)."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from typing import Any

from netapp_middleware.app import create_app
from netapp_middleware.services import Services
from netapp_operator.constants import MIDDLEWARE_MANAGER, NETAPP_KIND

from netapp.serve_process import free_port
from tests.support.polling import DEADLINE_S, wait_until  # noqa: F401 (the middleware tests import it from here)

ROBOTS = {"robot-1": "secret-one", "robot-2": "secret-two"}


class LoopThread:
    """An asyncio loop in a daemon thread; `call(coro)` runs a coroutine there and returns its result."""

    def __init__(self, name: str) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name=name, daemon=True)
        self.thread.start()

    def call(self, coro: Any, timeout: float = DEADLINE_S) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def stop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


class NullBackend:
    """A backend that runs nothing: for tests of the registry and the API alone."""

    name = "null"

    async def start(self, report):
        return []

    async def create(self, name, app, placement, spec, labels, annotations=None): ...
    async def record(self, name, claims): ...
    async def delete(self, name): ...
    async def announce(self, name, type_, reason, message): ...
    async def close(self): ...


class MiddlewareServer:
    """The middleware app served by uvicorn on a free loopback port, in a thread."""

    def __init__(self, services: Services) -> None:
        import uvicorn

        self.services = services
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        config = uvicorn.Config(
            create_app(services), host="127.0.0.1", port=self.port, log_level="warning", lifespan="on"
        )
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, name="middleware", daemon=True)

    def __enter__(self) -> MiddlewareServer:
        self.thread.start()
        wait_until(lambda: self.server.started or not self.thread.is_alive(), what="the middleware to start")
        assert self.server.started, "the middleware did not start"
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(DEADLINE_S)
        assert not self.thread.is_alive(), "the middleware did not stop"


NS = "robots"  # the namespace of the tests' NetApps


class Operator:
    """The test's stand-in for the operator: reads NetApps and writes their status through the API server."""

    def __init__(self, cluster: EmulatedCluster) -> None:
        self.cluster = cluster

    def netapps(self) -> dict[str, dict[str, Any]]:
        items = self.cluster.run(self.cluster.kube.list(NETAPP_KIND, NS))
        return {item["metadata"]["name"]: item for item in items}

    def create(self, netapp: dict[str, Any]) -> None:
        self.cluster.run(self.cluster.kube.create(netapp))

    def delete(self, name: str) -> None:
        self.cluster.run(self.cluster.kube.delete(NETAPP_KIND, NS, name))

    def the_one(self) -> dict[str, Any]:
        netapps = wait_until(self.netapps, what="a NetApp")
        assert len(netapps) == 1, netapps
        return next(iter(netapps.values()))

    def set_status(self, name: str, phase: str, url: str | None = None, pool: str | None = None) -> None:
        status: dict[str, Any] = {
            "phase": phase,
            "conditions": [
                {"type": "Ready", "status": str(phase == "Ready"), "reason": phase, "message": f"test says {phase}"}
            ],
        }
        if url:
            status.update(url=url, pool=pool)
        self.cluster.run(self.cluster.kube.patch_status(NETAPP_KIND, NS, name, status))


class Kubelet:
    """The tests' kubelet: serves real netapp processes on loopback (through the local backend, so that starting
    and stopping them is the production code) at URLs that the test then writes into NetApp status."""

    def __init__(self, model: str) -> None:
        from netapp_middleware.backends.local import LocalBackend

        self.runner = LoopThread("kubelet")
        self.ports: dict[str, int] = {}  # a fixed port for a name, e.g. a Service's NodePort
        self.backend = LocalBackend(
            model=model, ready_timeout_s=2 * DEADLINE_S, port_for=lambda name: self.ports.get(name) or free_port()
        )
        self._states: dict[str, Any] = {}
        self._changed = threading.Condition()
        self.runner.call(self.backend.start(self._report))

    def _report(self, name: str, state: Any) -> None:
        with self._changed:
            self._states[name] = state
            self._changed.notify_all()

    def serve(self, name: str, port: int | None = None, spec: dict[str, Any] | None = None) -> str:
        """Start a netapp (on `port`, else a free one; as `spec` says, a NetApp's, else the app's defaults) and
        return its URL once /readyz answers."""
        if port is not None:
            self.ports[name] = port
        self.runner.call(self.backend.create(name, "object-detection", None, spec or {}, {}))
        with self._changed:
            done = self._changed.wait_for(
                lambda: name in self._states and self._states[name].phase in ("Ready", "Failed"), 2 * DEADLINE_S
            )
        assert done and self._states[name].phase == "Ready", self._states.get(name)
        return str(self._states[name].url)

    def stop(self, name: str) -> None:
        self.runner.call(self.backend.delete(name))

    def close(self) -> None:
        self.runner.call(self.backend.close())
        self.runner.stop()


def send_until_result(send: Callable[[], Any], results: Any, timeout: float = DEADLINE_S) -> Any:
    """Send a frame, then another each time no result came within half a second; return the first result.
    `results` is a queue.Queue the client's result callback feeds."""
    import queue

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        send()
        try:
            return results.get(timeout=0.5)
        except queue.Empty:
            continue
    raise AssertionError(f"no result within {timeout:.0f} s")


def era_leave(robot: Any) -> None:
    """An era-5g-client robot leaves: it deletes its plan (its own call), then disconnects in the background,
    because python-engineio's threaded client can wait out a ping interval in disconnect() (upstream race)."""
    if robot.resource_checker is not None:
        robot.resource_checker.stop()
    robot.delete_all_resources()
    threading.Thread(target=robot.disconnect, daemon=True).start()


class EmulatedCluster:
    """The API emulator (kmock plus what the operator relies on, from tests/support/kube_emulator.py) in a thread,
    with the project's CRDs; reached through `.kubeconfig` like any cluster: `.kube` is the tests' own client (`run`
    runs its calls on the emulator's loop), `new_kube()` a client for a middleware."""

    def __init__(self, tmp_path: Any) -> None:
        import kmock
        from netapp_operator.kube import Kube

        from tests.support.kube_emulator import Emulator, declare, kubeconfig

        self.runner = LoopThread("emulator")
        self._stop = asyncio.Event()
        started: dict[str, str] = {}

        async def serve() -> None:
            async with Emulator() as emulator, kmock.Server(emulator) as server:
                declare(emulator)
                self.emulator = emulator
                started["url"] = str(server.url).rstrip("/")
                await self._stop.wait()

        self._future = asyncio.run_coroutine_threadsafe(serve(), self.runner.loop)
        wait_until(lambda: "url" in started or self._future.done(), what="the API emulator")
        self.url = started["url"]
        self.kubeconfig = tmp_path / "kubeconfig"
        self.kubeconfig.write_text(kubeconfig(self.url))
        self.kube = Kube(self._login, manager="netapp-middleware-tests")

    async def _login(self) -> Any:
        from netapp_operator.kube import environment_login

        return await environment_login(str(self.kubeconfig))

    def new_kube(self) -> Any:
        """A client for one middleware (it binds to the loop of its first call, and the backend closes it)."""
        from netapp_operator.kube import Kube

        return Kube(self._login, manager=MIDDLEWARE_MANAGER)

    def run(self, coro: Any) -> Any:
        return self.runner.call(coro)

    def forget(self, name: str) -> None:
        """Remove an object behind every watch's back (no event), as if it went while no watch was open."""

        async def drop() -> None:
            for (_, _, object_name), obj in list(self.emulator.objects.items()):
                if object_name == name and not obj.deleted:
                    obj.delete()

        self.runner.call(drop())

    def close(self) -> None:
        self.run(self.kube.close())
        self.runner.loop.call_soon_threadsafe(self._stop.set)
        self._future.result(30)
        self.runner.stop()
