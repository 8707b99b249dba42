"""A WATCH at a replica that does not pull the camera: relayed from the replica holding its Lease (two real `netapp
serve` processes sharing Leases on the Kubernetes API emulator, a real `netapp watch` at the other one), followed when
the holder changes; and the cameras' results written by the netapp itself (`--source-results`, rotated)."""

from __future__ import annotations

import json
import logging
import subprocess
import sys

import pytest

from netapp.framing import ACK_EVENT, read_event
from netapp.protocol import RESULTS_EVENT
from netapp.serve_process import NetAppProcess
from netapp.server.sources.relay import holder_url
from netapp.server.sources.results_file import KEEP, ResultsFiles
from tests.netapp.server.test_frames import metric
from tests.support.api_emulator import ApiEmulator
from tests.support.polling import wait_until
from tests.support.watcher import Watcher

UP = 'netapp_source_up{source="door"}'


def test_only_another_replicas_address_is_relayed_from():
    me = "http://10.0.0.1:5896"
    assert holder_url("http://10.0.0.2:5896", me) == "http://10.0.0.2:5896"
    assert holder_url(me, me) is None  # ours: nothing to relay
    assert holder_url("", me) is None  # given back: nobody holds it
    assert holder_url("det-7f9c-xk2p", me) is None  # a pod's name is no address
    assert holder_url("file:///etc/passwd", me) is None
    assert holder_url("http://" + "a" * 3000, me) is None


def test_the_holders_events_are_read_and_anything_else_ignored():
    assert read_event('{"event": "ack", "ok": true}') == (ACK_EVENT, {"event": ACK_EVENT, "ok": True})
    assert read_event(json.dumps({"event": RESULTS_EVENT, "data": {}}))[0] == RESULTS_EVENT
    for junk in (b"\x00binary", "[1, 2]", "not json", '{"event": 3}', "null"):
        assert read_event(junk) is None


def test_results_files_rotate_and_keep_a_bounded_number(tmp_path):
    files = ResultsFiles(tmp_path / "results", max_bytes=300)
    for i in range(40):
        files.write("door", {"timestamp": i, "detections": [], "source": "door"})
    files.close()
    path = tmp_path / "results" / "door.jsonl"
    old = sorted(path.parent.glob("door.jsonl.*"))
    assert [p.name for p in old] == [f"door.jsonl.{i}" for i in range(1, KEEP + 1)]  # no more than KEEP
    for p in [path, *old]:
        assert 0 < p.stat().st_size <= 300
        assert all(json.loads(line)["source"] == "door" for line in p.read_text().splitlines())  # whole lines only
    assert json.loads(path.read_text().splitlines()[-1])["timestamp"] == 39  # the newest is in the current file


def test_a_results_folder_that_cannot_be_written_is_said_once_and_nothing_stops(tmp_path, caplog):
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    files = ResultsFiles(blocked / "results")  # its parent is a file: every write fails
    with caplog.at_level(logging.ERROR, "netapp.server.sources.results_file"):
        for i in range(5):
            files.write("door", {"timestamp": i})
    [line] = [r.getMessage() for r in caplog.records]
    assert line.startswith("camera door: cannot write its results to") and "dropping them" in line
    files.close()


def test_a_watch_at_the_replica_without_the_camera_is_relayed_and_follows_a_new_holder(
    cameras, tiny_model_path, tmp_path, monkeypatch
):
    pytest.importorskip("kmock", reason="kmock is not installed (pip install '.[test]')")
    from tests.support.kube_emulator import kubeconfig

    camera = cameras()
    with ApiEmulator() as api:
        config = tmp_path / "kubeconfig"
        config.write_text(kubeconfig(api.url))
        monkeypatch.setenv("KUBECONFIG", str(config))  # the netapps' own client, over httpx
        monkeypatch.setenv("NETAPP_NAME", "det")
        monkeypatch.delenv("KUBERNETES_SERVICE_HOST", raising=False)

        def replica(name: str) -> NetAppProcess:
            return NetAppProcess(
                *("--model", str(tiny_model_path), "--source", f"door={camera.url}", "--camera-leases", "robots"),
                *("--source-results", str(tmp_path / name), "--drain-grace", "0.5"),
                advertise=True,
            ).start()

        first = replica("first").wait_ready()
        wait_until(lambda: metric(first.url, UP) == 1, 30, "the first replica to pull the camera")
        second = replica("second").wait_ready()
        try:
            wait_until(lambda: api.lease("robots", "det-camera-door") is not None, 10, "the Lease")
            assert api.lease("robots", "det-camera-door")["spec"]["holderIdentity"] == first.url
            # a watcher of the second replica, through the real command line: results relayed from the first
            watch = subprocess.run(
                [sys.executable, "-m", "netapp", "watch", second.url, "--source", "door", "--count", "3"],
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert watch.returncode == 0, watch.stderr
            lines = [json.loads(line) for line in watch.stdout.splitlines()]
            assert len(lines) == 3 and all(m["source"] == "door" and m["detections"] for m in lines)
            assert metric(second.url, 'netapp_source_pictures_decoded_total{source="door"}') == 0  # not pulled twice
            assert metric(second.url, 'netapp_source_relays_total{outcome="connected",source="door"}') >= 1

            # the first replica stops: the second takes the camera, and its watcher goes on with its own results
            with Watcher(second.url, "door") as watcher:
                wait_until(lambda: watcher.count() >= 2, 30, "relayed results")
                first.process.terminate()  # SIGTERM: it gives its Lease back
                first.process.wait(timeout=30)
                wait_until(lambda: metric(second.url, UP) == 1, 30, "the second replica to take the camera")
                taken = watcher.count()
                wait_until(lambda: watcher.count() >= taken + 3, 30, "results from the new holder")
                assert watcher.error is None
            assert metric(second.url, 'netapp_source_subscribers{source="door"}') == 0  # the watcher left
        finally:
            first.kill()
            second.kill()
    # the holder wrote the results itself, one JSON line each; the second only once it pulled the camera
    written = (tmp_path / "first" / "door.jsonl").read_text().splitlines()
    assert written and all(json.loads(line)["source"] == "door" for line in written)
