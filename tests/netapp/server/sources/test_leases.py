"""Which replica pulls a camera: the Lease decisions (pure), and two netapps sharing a camera through Leases on the
Kubernetes API emulator, the second taking over when the first stops."""

from __future__ import annotations

import datetime
import itertools
import json
import time

import pytest
from websockets.sync.client import connect

from netapp.client.watch import subscribe
from netapp.framing import ACK_EVENT, frames_url
from netapp.protocol import FORWARDED_HEADER, SOURCE_FIELD, CommandType
from netapp.server.settings import Settings
from netapp.server.sources.leases import CREATE, LEASE_S, RENEW, TAKE, WAIT, decide, lease_manifest, lease_name
from netapp.server.sources.naming import parse_source
from tests.netapp.server.test_frames import metric
from tests.support.api_emulator import ApiEmulator
from tests.support.polling import wait_until
from tests.support.watcher import Watcher

NOW = datetime.datetime(2026, 11, 27, 12, 0, 0, tzinfo=datetime.timezone.utc)


def held_by(holder: str, seconds_ago: float) -> dict:
    return lease_manifest("n-camera-door", "robots", holder, NOW - datetime.timedelta(seconds=seconds_ago))


def test_a_lease_is_created_renewed_waited_for_or_taken_when_expired_or_given_back():
    assert decide(None, "a", NOW) == CREATE
    assert decide(held_by("a", 1), "a", NOW) == RENEW
    assert decide(held_by("b", 1), "a", NOW) == WAIT
    assert decide(held_by("b", LEASE_S - 0.5), "a", NOW) == WAIT
    assert decide(held_by("b", LEASE_S + 0.5), "a", NOW) == TAKE  # b stopped renewing
    given_back = held_by("b", 1)
    given_back["spec"]["holderIdentity"] = ""
    assert decide(given_back, "a", NOW) == TAKE
    broken = held_by("b", 1)
    broken["spec"]["renewTime"] = "yesterday"
    assert decide(broken, "a", NOW) == TAKE  # a Lease nobody can read the time of is nobody's


def test_a_taken_lease_counts_its_transitions_and_names_are_dns_subdomains():
    first = held_by("b", 30)
    taken = lease_manifest("n-camera-door", "robots", "a", NOW, first)
    assert taken["spec"]["holderIdentity"] == "a" and taken["spec"]["leaseTransitions"] == 1
    assert (
        taken["spec"]["renewTime"] == "2026-11-27T12:00:00.000000Z" and taken["spec"]["leaseDurationSeconds"] == LEASE_S
    )
    assert lease_name("Det", "Front_Door") == "det-camera-front-door"


def forwarded_watch(url: str, source: str) -> dict:
    """The answer to a WATCH sent as another replica's relay sends it (X-Netapp-Forwarded)."""
    headers = {FORWARDED_HEADER: "1"}
    with connect(frames_url(url), additional_headers=headers, open_timeout=10) as ws:
        ws.send(json.dumps({"cmd_type": int(CommandType.WATCH), "id": 1, "data": {SOURCE_FIELD: source}}))
        while True:
            message = json.loads(ws.recv(timeout=10))
            if message.get("event") == ACK_EVENT:
                return message


def test_two_replicas_share_a_camera_through_a_lease_and_the_second_takes_over(
    cameras, serve, tiny_detector, tmp_path, monkeypatch
):
    pytest.importorskip("kmock", reason="kmock is not installed (pip install '.[test]')")
    from tests.support.kube_emulator import kubeconfig

    camera = cameras()
    with ApiEmulator() as api:
        config = tmp_path / "kubeconfig"
        config.write_text(kubeconfig(api.url))
        monkeypatch.setenv("KUBECONFIG", str(config))
        monkeypatch.delenv("KUBERNETES_SERVICE_HOST", raising=False)

        def replica(name: str):
            settings = Settings(
                lanes=1,
                sources=(parse_source(f"door={camera.url}"),),
                camera_leases="robots",
                advertise_url=f"http://{name}:5896",  # its identity in the Lease
                netapp_name="det",
            )
            return serve(tiny_detector, settings)

        first = replica("first")
        # until its Lease round has run, a replica pulls nothing and refuses WATCH (`elsewhere`)
        wait_until(lambda: metric(first.url, 'netapp_source_up{source="door"}') == 1, 30, "the first to pull it")
        with Watcher(first.url, "door") as watcher:
            wait_until(lambda: watcher.count() >= 3, 30, "results from the replica holding the Lease")
        assert api.lease("robots", "det-camera-door")["spec"]["holderIdentity"] == "http://first:5896"

        second = replica("second")
        # it holds no Lease: it pulls nothing; a WATCH that is itself another replica's relay is not relayed again
        # (no loop between two replicas that read the Lease at different moments): it says where to go
        assert forwarded_watch(second.url, "door")["reason"] == "elsewhere"
        assert metric(second.url, 'netapp_source_pictures_decoded_total{source="door"}') == 0

        first.stop()  # gives its Lease back: the second takes the camera at its next round
        # `netapp watch` tries again while it is told `elsewhere`, until the second replica pulls the camera
        with subscribe(second.url, "door") as subscription:
            got = list(itertools.islice(subscription.results(until=time.monotonic() + 20), 3))
        assert len(got) == 3 and metric(second.url, 'netapp_source_up{source="door"}') == 1
        lease = api.lease("robots", "det-camera-door")["spec"]
        assert lease["holderIdentity"] == "http://second:5896" and lease["leaseTransitions"] == 1
