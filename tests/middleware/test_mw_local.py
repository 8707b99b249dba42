"""The local backend end to end: real netapp processes, a robot deploys, streams, gets detections, deletes; and
no netapp outlives the middleware, however it stops."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import psutil
import pytest
import requests
from netapp_middleware.backends.local import LocalBackend

from netapp.client.middleware import MiddlewareClient, MiddlewareError
from netapp.client.netapp_client import NetAppClient
from tests.middleware.mw_helpers import DEADLINE_S, ROBOTS, era_leave, free_port, send_until_result, wait_until
from tests.support.paths import ROOT


def gone(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def test_local_backend_end_to_end(start_middleware: Any, tiny_model_path: Path, jpeg: bytes) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend)
    seen: list[str] = []
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy(
            "object-detection",
            placement="edge",
            timeout=2 * DEADLINE_S,
            on_progress=lambda view: seen.append(view["status"]),
        )
        assert seen[0] in ("Pending", "Deploying") and seen[-1] == "Ready"
        assert endpoint.url.startswith("http://127.0.0.1:") and endpoint.pool == "edge"  # the placement's pool
        (pid,) = backend.pids().values()
        results: queue.Queue[Any] = queue.Queue()
        with mw.netapp_client(endpoint, transport="ws", on_result=results.put) as client:
            result = send_until_result(lambda: client.send(jpeg), results)
        assert [d["class_name"] for d in result.detections] == ["robot"]
        # A second robot reusing the app shares the same process.
        with MiddlewareClient(server.url, "robot-2", ROBOTS["robot-2"]) as other:
            assert other.deploy("object-detection", placement="edge", timeout=DEADLINE_S).url == endpoint.url
        assert backend.pids() == {next(iter(backend.pids())): pid} and not gone(pid)
    # Leaving the block deleted the deployment: the netapp process is stopped.
    assert backend.pids() == {} and gone(pid)


def test_a_hedged_deployment_runs_a_netapp_on_each_placement(
    start_middleware: Any, tiny_model_path: Path, jpeg: bytes
) -> None:
    """`hedge: [edge, cloud]`: two netapps for one robot, both URLs in the endpoint, both serve; deleting the
    deployment stops both."""
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend)
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("object-detection", hedge=["edge", "cloud"], timeout=2 * DEADLINE_S)
        assert len(endpoint.urls) == 2 and endpoint.url == endpoint.urls[0] and len(set(endpoint.urls)) == 2
        view = mw.status(endpoint)
        assert [(h["placement"], h["pool"], h["status"]) for h in view["hedge"]] == [
            ("edge", "edge", "Ready"),
            ("cloud", "cloud", "Ready"),
        ]
        pids = list(backend.pids().values())
        assert len(pids) == 2
        for url in endpoint.urls:
            results: queue.Queue[Any] = queue.Queue()
            with NetAppClient(url, transport="ws", on_result=results.put) as client:
                assert send_until_result(lambda c=client: c.send(jpeg), results).detections
        # The middleware's client hands both to one NetAppClient, which hedges each frame.
        results = queue.Queue()
        with mw.netapp_client(endpoint, policy="hedge", transport="ws", on_result=results.put) as client:
            assert client.urls == endpoint.urls
            assert send_until_result(lambda: client.send(jpeg), results).detections
        with pytest.raises(MiddlewareError, match="either placement or hedge"):
            mw.create("object-detection", placement="edge", hedge=["edge", "cloud"])
    assert backend.pids() == {} and all(gone(pid) for pid in pids)


def test_a_netapp_that_cannot_start_fails_the_deployment(start_middleware: Any, tmp_path: Path) -> None:
    server = start_middleware(LocalBackend(model=str(tmp_path / "missing.onnx"), ready_timeout_s=DEADLINE_S))
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        with pytest.raises(Exception, match="exited with code"):
            mw.deploy("object-detection", timeout=2 * DEADLINE_S)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["sigterm", "sigkill"])
def test_no_netapp_outlives_the_middleware(sig: int, robots_file: Path, tiny_model_path: Path) -> None:
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    middleware = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "netapp",
            "middleware",
            "--backend",
            "local",
            "--model",
            str(tiny_model_path),
            "--robots-file",
            str(robots_file),
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
        ],
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:

        def healthy() -> bool:
            assert middleware.poll() is None, "the middleware exited"
            try:
                return requests.get(f"{url}/healthz", timeout=2).ok
            except requests.RequestException:
                return False

        wait_until(healthy, what="the middleware to answer /healthz")
        mw = MiddlewareClient(url, "robot-1", ROBOTS["robot-1"])
        endpoint = mw.deploy("object-detection", timeout=2 * DEADLINE_S)
        assert requests.get(f"{endpoint.url}/readyz", timeout=5).status_code == 200
        netapps = [p for p in psutil.Process(middleware.pid).children(recursive=True) if "serve" in p.cmdline()]
        assert len(netapps) == 1
        # A robot's follower keeps a long poll open (30 s): a graceful stop must not wait for it.
        following = mw.follow(endpoint, lambda new: None)
        middleware.send_signal(sig)
        middleware.wait(20)
        following.set()
        wait_until(lambda: all(gone(p.pid) for p in netapps), what="the netapp process to stop")
    finally:
        if middleware.poll() is None:
            middleware.kill()
            middleware.wait()


def test_demo_runs_the_whole_flow_from_the_command_line(tiny_model_path: Path, tmp_path: Path, jpeg: bytes) -> None:
    """`make demo`'s command: middleware, `netapp stream --middleware` (deploy, stream, results, delete)."""
    image = tmp_path / "frame.jpg"
    image.write_bytes(jpeg)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "netapp",
            "middleware",
            "demo",
            "--model",
            str(tiny_model_path),
            "--source",
            str(image),
            "--duration",
            "2",
            "--fps",
            "5",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=3 * DEADLINE_S,
    )
    output = done.stdout + done.stderr
    assert done.returncode == 0, output
    assert "deployed object-detection on edge: http://127.0.0.1:" in output  # the placement names the pool
    assert "robot x" in output  # the summary's detections
    assert "no netapp left running" in output


def test_era_robot_on_the_local_backend_detects_with_yolox_nano(
    start_middleware: Any, real_model_path: Path, media_dir: Path
) -> None:
    """The catalogue's object-detection task with the real YOLOX-Nano, planned and used by an unmodified
    era-5g-client robot: the dog in dog.jpg is found; deleting the plan stops the netapp process."""
    era = pytest.importorskip("era_5g_client.client", reason="era-5g-client is installed by `make install`")
    import cv2
    from era_5g_client.dataclasses import MiddlewareInfo
    from era_5g_interface.channels import CallbackInfoClient, ChannelType
    from netapp_middleware.catalogue import OBJECT_DETECTION_TASK_ID

    backend = LocalBackend(model=str(real_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend)
    results: queue.Queue[Any] = queue.Queue()
    robot = era.NetAppClient(callbacks_info={"results": CallbackInfoClient(ChannelType.JSON, results.put)})
    robot.connect_to_middleware(MiddlewareInfo(server.url.removeprefix("http://"), "robot-1", ROBOTS["robot-1"]))
    try:
        robot.run_task(OBJECT_DETECTION_TASK_ID, "3f7f5d8e-6a0b-4c39-9a55-2f0f3c6f3b11", resource_lock=True)
        (pid,) = backend.pids().values()
        frame = cv2.imread(str(media_dir / "dog.jpg"))
        result = send_until_result(lambda: robot.send_image(frame, "image", ChannelType.JPEG, time.time_ns()), results)
        assert "dog" in {d["class_name"] for d in result["detections"]}
    finally:
        era_leave(robot)
    wait_until(lambda: not backend.pids() and gone(pid), what="the netapp process to stop")


def test_the_local_backend_leaves_no_folder_behind(tmp_path, monkeypatch, tiny_model_path):
    """Its netapps' logs live in a temporary folder made with the first netapp, gone with the last one and at close
    (with a failed netapp's log), never one left per backend in /tmp (`make test` once left a hundred)."""
    import asyncio
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    folders = lambda: sorted(p.name for p in tmp_path.glob("netapp-middleware-*"))  # noqa: E731
    idle = [sys.executable, "-c", "import time; time.sleep(60)"]  # a netapp that never gets ready: it is not judged
    failing = [sys.executable, "-c", "raise SystemExit('no model')"]

    async def lifecycle() -> None:
        unused = LocalBackend(model=str(tiny_model_path), command=idle)
        await unused.close()
        assert folders() == []  # never used: never made
        backend = LocalBackend(model=str(tiny_model_path), command=idle, ready_timeout_s=60)
        await backend.start(lambda name, state: None)
        await backend.create("a", "detect", None, {}, {})
        await backend.create("b", "detect", None, {}, {})
        assert len(folders()) == 1
        await backend.delete("a")
        assert len(folders()) == 1  # b's log is there
        await backend.delete("b")
        assert folders() == []
        backend.command = failing
        await backend.create("c", "detect", None, {}, {})
        await asyncio.sleep(0.5)  # c has failed, and its log stays for its reason, until close
        await backend.close()
        assert folders() == []

    asyncio.run(lifecycle())
