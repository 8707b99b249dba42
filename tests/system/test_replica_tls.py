"""TLS between replicas (docs/security.md#tls-between-replicas): real `netapp serve` replicas serving HTTPS on
loopback, with certificates from CAs made here. A frame and a WebSocket forwarded over TLS work, verified against
the peer CA or against the replica's own certificate; a replica with a certificate from another CA is refused,
with one log line naming it, counted, and the robot answered at once."""

from __future__ import annotations

import json
import os
import ssl
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import requests
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from netapp.protocol import PEER_CA_ENV
from tests.support.certificates import certificate_authority
from tests.support.images import make_jpeg
from tests.support.replicas import Replicas

REFUSED = 'netapp_peer_tls_refused_total{reason="certificate"}'
FORWARDED = 'netapp_forwarded_total{kind="%s"}'


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("replica-tls")


@pytest.fixture(scope="module")
def replicas(tiny_model_path, folder) -> Iterator[Replicas]:
    """0 and 1 share one certificate from CA a (0 verifies peers against CA a, 1 against its own certificate); 2
    has a certificate from CA b. The robots here trust both CAs."""
    ca, other = certificate_authority(folder / "a"), certificate_authority(folder / "b")
    shared = ("--tls-cert", "--tls-key")
    shared_files = ca.issue(folder / "shared")
    stranger_files = other.issue(folder / "stranger")
    trusted = folder / "robots-trust.pem"
    trusted.write_text(ca.cert.read_text() + other.cert.read_text())
    args = [
        (*_tls(shared, shared_files), "--peer-ca", str(ca.cert)),
        _tls(shared, shared_files),
        (*_tls(shared, stranger_files), "--peer-ca", str(other.cert)),
    ]
    with pytest.MonkeyPatch.context() as env:
        env.setenv("REQUESTS_CA_BUNDLE", str(trusted))  # the robots' (and the readiness poll's) trust
        env.delenv(PEER_CA_ENV, raising=False)
        with Replicas(tiny_model_path, 3, scheme="https", replica_args=args, balanced=False) as started:
            started.trusted = trusted
            yield started


def _tls(flags: tuple[str, str], files: tuple[Path, Path]) -> tuple[str, ...]:
    return (flags[0], str(files[0]), flags[1], str(files[1]))


def register(url: str) -> str:
    answer = requests.post(f"{url}/register", json={"robot_id": "tls"}, timeout=10)
    assert answer.status_code == 201, answer.text
    return answer.json()["session_id"]


def send(url: str, token: str, timestamp: int, wait: bool = False) -> requests.Response:
    headers = {"X-Session-Id": token, "X-Timestamp": str(timestamp), "Content-Type": "image/jpeg"}
    return requests.post(
        f"{url}/send_image", params={"wait": str(wait).lower()}, data=make_jpeg(), headers=headers, timeout=10
    )


def poll_results(url: str, token: str, timeout_s: float = 20.0) -> list[int]:
    deadline = time.monotonic() + timeout_s
    while True:
        answer = requests.get(f"{url}/results", headers={"X-Session-Id": token}, timeout=10)
        assert answer.status_code == 200, answer.text
        got = [r["timestamp"] for r in answer.json()["results"]]
        if got or answer.json()["dropped"]:
            return got
        assert time.monotonic() < deadline, "no result polled in time"
        time.sleep(0.05)  # polling with a deadline


@pytest.mark.parametrize("owner, landing", [(0, 1), (1, 0)], ids=["own-certificate", "peer-ca"])
def test_a_frame_and_its_results_are_forwarded_to_the_owner_over_tls(replicas, owner, landing):
    token = register(replicas.urls[owner])
    forwarded = replicas.metric(landing, FORWARDED % "http")
    answer = send(replicas.urls[landing], token, 7)  # a polled frame: forwarded to the owner, who keeps its result
    assert answer.status_code == 202, answer.text
    assert poll_results(replicas.urls[landing], token) == [7]
    assert replicas.metric(landing, FORWARDED % "http") >= forwarded + 2
    assert replicas.metric(landing, REFUSED) == 0


def engineio_sid(url: str) -> str:
    answer = requests.get(f"{url}/socket.io/", params={"EIO": 4, "transport": "polling"}, timeout=10)
    assert answer.status_code == 200 and answer.text.startswith("0"), answer.text
    return json.loads(answer.text[1:])["sid"]


def upgrade(replicas: Replicas, sid: str, landing: int):
    context = ssl.create_default_context(cafile=str(replicas.trusted))
    url = replicas.urls[landing].replace("https://", "wss://")
    return connect(f"{url}/socket.io/?EIO=4&transport=websocket&sid={sid}", ssl=context, open_timeout=10)


def test_a_websocket_upgrade_is_relayed_to_its_owner_over_tls(replicas):
    sid = engineio_sid(replicas.urls[0])
    with upgrade(replicas, sid, landing=1) as socket:  # relayed by 1 to 0 over WSS
        socket.send("2probe")
        assert socket.recv(timeout=10) == "3probe"  # the owner's answer to an Engine.IO upgrade probe
    assert replicas.metric(1, FORWARDED % "websocket") >= 1


def wait_for_log(replicas: Replicas, i: int, words: str, timeout_s: float = 10.0) -> list[str]:
    deadline = time.monotonic() + timeout_s
    while True:
        lines = [line for line in replicas.log(i, tail=100_000).splitlines() if words in line]
        if lines:
            return lines
        assert time.monotonic() < deadline, f"replica {i} never logged {words!r}: {replicas.log(i)}"
        time.sleep(0.05)  # polling with a deadline


def test_a_replica_with_a_certificate_from_another_ca_is_refused_logged_and_counted(replicas):
    stranger = replicas.urls[2]
    token = register(stranger)
    refused = replicas.metric(0, REFUSED)
    started = time.monotonic()
    answer = requests.get(f"{replicas.urls[0]}/results", headers={"X-Session-Id": token}, timeout=10)
    assert answer.status_code == 503 and answer.json()["reason"] == "owner_gone", answer.text
    assert time.monotonic() - started < 10  # answered, not hung (the request's own timeout would raise)
    assert replicas.metric(0, REFUSED) == refused + 1
    lines = wait_for_log(replicas, 0, f"refused the replica at {stranger}")
    assert "its TLS certificate is not one --peer-ca vouches for" in lines[-1]
    # its WebSocket is refused as well (closed at once), and so is the revocation check of a wait=true frame, which is
    # still served where it lands (an owner out of reach revokes nothing)
    with pytest.raises(InvalidStatus):  # closed before it was accepted: the handshake is refused
        upgrade(replicas, engineio_sid(stranger), landing=0)
    assert send(replicas.urls[0], token, 8, wait=True).status_code == 200
    assert replicas.metric(0, REFUSED) >= refused + 3
    assert replicas.metric(2, REFUSED) == 0  # nobody tried to reach a peer from 2


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--advertise-url", "http://127.0.0.1:5896", "--tls"], "advertise it as --advertise-url https://"),
        (["--advertise-url", "https://127.0.0.1:5896"], "--advertise-url https:// is for a replica that serves"),
        (["--advertise-url", "https://127.0.0.1:5896", "--tls", "--peer-ca", "/nonexistent.pem"], "cannot verify"),
    ],
)
def test_netapp_serve_refuses_a_replica_whose_tls_cannot_work_in_one_line(tiny_model_path, folder, extra, words):
    cert, key = certificate_authority(folder / "cli").issue(folder / "cli-cert")
    key_file = folder / "cluster.key"
    key_file.write_text("k" * 64)
    tls = ["--tls-cert", str(cert), "--tls-key", str(key)]
    extra = [arg for item in extra for arg in (tls if item == "--tls" else [item])]
    argv = [
        sys.executable,
        "-m",
        "netapp",
        "serve",
        "--model",
        str(tiny_model_path),
        "--cluster-key-file",
        str(key_file),
    ]
    done = subprocess.run([*argv, *extra], capture_output=True, text=True, timeout=60, env=dict(os.environ))
    assert done.returncode == 2 and words in done.stderr, done.stderr
