"""Tests of bench/linkemu against a real TCP echo server on 127.0.0.1.

Timing assertions are lower bounds plus generous upper bounds only. Tests that need the kernel
path (root, iproute2, network namespaces) skip with the reason when it is unavailable.
"""

from __future__ import annotations

import logging
import os
import random
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from bench.linkemu import (
    PROFILES,
    LinkEmulator,
    LinkProfile,
    detect_capabilities,
    emulated_link,
    get_profile,
    list_namespaces,
)
from bench.linkemu import netns as netns_mod
from bench.linkemu.relay import MSS, RTO_MIN_S, DirectionModel, RateClock
from tests.support.echo import EchoServer, recv_exact
from tests.support.echo import open_echo as _open
from tests.support.paths import ROOT

pytestmark = pytest.mark.timeout(60)

CAPS = detect_capabilities()
needs_netns = pytest.mark.skipif(not CAPS.netns, reason=f"netns mode unavailable: {CAPS.reason}")
MODES = [pytest.param("netns", marks=needs_netns), "userspace"]
# Each relay direction may fire up to 0.5 ms early (sleeps are rounded to the nearest ms).
EARLY_TOLERANCE_S = 0.002


def _target(srv: EchoServer) -> tuple[str, int]:
    return srv.target


def _profile(
    name: str = "t",
    delay: float = 0.0,
    jitter: float = 0.0,
    loss: float = 0.0,
    up: float | None = None,
    down: float | None = None,
) -> LinkProfile:
    return LinkProfile(name, delay, jitter, loss, up, down)


# -- profiles and models (no network) ----------------------------------------------------------


def test_profiles_are_sane() -> None:
    assert {"loopback", "wifi", "5g"} <= set(PROFILES)
    assert PROFILES["loopback"].is_passthrough
    for name in ("wifi", "5g"):
        p = get_profile(name.upper())
        assert not p.is_passthrough and p.delay_ms > 0 and p.loss_pct > 0
        # Every cited measurement has uplink well below downlink on these links.
        assert p.rate_mbit_up is not None and p.rate_mbit_down is not None
        assert p.rate_mbit_up < p.rate_mbit_down
    assert PROFILES["5g"].rtt_ms == 2 * PROFILES["5g"].delay_ms
    with pytest.raises(KeyError, match="known"):
        get_profile("carrier-pigeon")
    with pytest.raises(ValueError):
        LinkProfile("bad", -1, 0, 0, None, None)


def test_direction_model_delay_rate_and_loss() -> None:
    exact = DirectionModel(0.010)
    assert exact.release_time(100.0, 500) == pytest.approx(100.010)
    clock = RateClock(8e6)  # 1 byte per microsecond
    shaped = DirectionModel(0.010, rate=clock)
    assert shaped.release_time(0.0, 1000) == pytest.approx(0.011)
    # The link is busy until 1 ms, so a second chunk queues behind the first.
    assert shaped.release_time(0.0, 1000) == pytest.approx(0.012)
    lossy = DirectionModel(0.010, loss=1.0, rng=random.Random(1))
    # Small chunk: no duplicate ACKs possible, so the loss costs a retransmission timeout.
    assert lossy.release_time(0.0, 100) == pytest.approx(0.010 + RTO_MIN_S + 0.020)
    # Four segments or more: fast retransmit, one RTT.
    assert lossy.release_time(0.0, 4 * MSS) == pytest.approx(0.010 + 0.020)
    jittery = DirectionModel(0.010, jitter_s=0.004, rng=random.Random(2))
    samples = [jittery.release_time(0.0, 10) for _ in range(200)]
    assert min(samples) >= 0.006 - 1e-9 and max(samples) <= 0.014 + 1e-9


def test_loopback_profile_is_passthrough(echo_server: EchoServer) -> None:
    with emulated_link(PROFILES["loopback"], _target(echo_server)) as addr:
        assert addr == _target(echo_server)


# -- behaviour through the relay, both modes ---------------------------------------------------


@pytest.mark.parametrize("mode", MODES)
def test_rtt_includes_configured_delay(echo_server: EchoServer, mode: str) -> None:
    delay_s = 0.020
    with emulated_link(_profile(delay=delay_s * 1000), _target(echo_server), mode=mode) as addr:
        with _open(addr) as s:
            rtts = []
            for i in range(10):
                msg = f"ping {i:04d}".encode()
                t = time.perf_counter()
                s.sendall(msg)
                assert recv_exact(s, len(msg)) == msg
                rtts.append(time.perf_counter() - t)
    assert min(rtts) >= 2 * delay_s - EARLY_TOLERANCE_S
    assert statistics.median(rtts) < 2 * delay_s + 0.25


@pytest.mark.parametrize("mode", MODES)
def test_first_request_pays_the_handshake(echo_server: EchoServer, mode: str) -> None:
    delay_s = 0.015
    with emulated_link(_profile(delay=delay_s * 1000), _target(echo_server), mode=mode) as addr:
        t = time.perf_counter()
        with _open(addr) as s:
            s.sendall(b"x")
            assert recv_exact(s, 1) == b"x"
            elapsed = time.perf_counter() - t
    # connect (1 RTT, emulated by holding the first bytes) + request/response (1 RTT)
    assert elapsed >= 4 * delay_s - EARLY_TOLERANCE_S
    assert elapsed < 4 * delay_s + 0.5


@pytest.mark.parametrize("mode", MODES)
def test_large_payload_keeps_order_and_content(echo_server: EchoServer, mode: str) -> None:
    # Jitter as large as the delay would reorder chunks if the relay did not keep TCP order;
    # loss and a rate limit exercise retransmissions (netns) or their delay model (userspace).
    profile = _profile(delay=5, jitter=5, loss=1.0, up=200, down=200)
    payload = random.Random(42).randbytes(4 << 20)
    with emulated_link(profile, _target(echo_server), mode=mode, seed=7) as addr:
        with _open(addr) as s:
            sender = threading.Thread(target=s.sendall, args=(payload,))
            sender.start()
            echoed = recv_exact(s, len(payload))
            sender.join(timeout=30)
    assert echoed == payload


@pytest.mark.parametrize("mode", MODES)
def test_many_concurrent_connections(echo_server: EchoServer, mode: str) -> None:
    n_clients, n_messages = 40, 5

    def client(i: int) -> bool:
        with _open(addr) as s:
            for j in range(n_messages):
                msg = f"client {i:03d} message {j:02d} ".encode() * 20
                s.sendall(msg)
                if recv_exact(s, len(msg)) != msg:
                    return False
        return True

    with emulated_link(_profile(delay=5, jitter=2), _target(echo_server), mode=mode) as addr:
        with ThreadPoolExecutor(n_clients) as pool:
            results = list(pool.map(client, range(n_clients)))
    assert all(results)


@pytest.mark.parametrize("mode", MODES)
def test_client_close_reaches_server(echo_server: EchoServer, mode: str) -> None:
    while not echo_server.eofs.empty():
        echo_server.eofs.get_nowait()
    with emulated_link(_profile(delay=5), _target(echo_server), mode=mode) as addr:
        s = _open(addr)
        s.sendall(b"hello")
        assert recv_exact(s, 5) == b"hello"
        s.close()
        assert echo_server.eofs.get(timeout=5)


@pytest.mark.parametrize("mode", MODES)
def test_half_close_then_reply(echo_server: EchoServer, mode: str) -> None:
    # HTTP/1.0-style: the client shuts its sending side, the server still answers, then closes.
    with emulated_link(_profile(delay=5), _target(echo_server), mode=mode) as addr:
        with _open(addr) as s:
            s.sendall(b"request body")
            s.shutdown(socket.SHUT_WR)
            assert recv_exact(s, 12) == b"request body"
            assert s.recv(1) == b""


@pytest.mark.parametrize("mode", MODES)
def test_server_close_reaches_client(echo_server: EchoServer, mode: str) -> None:
    with emulated_link(_profile(delay=5), _target(echo_server), mode=mode) as addr:
        with _open(addr, b"C") as s:
            assert s.recv(1) == b""  # EOF within the socket timeout, not a hang


@pytest.mark.parametrize("mode", MODES)
def test_unreachable_target_closes_client(mode: str) -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        dead = probe.getsockname()  # bound but not listening: connections are refused
        with emulated_link(_profile(delay=1), dead, mode=mode) as addr:
            with socket.create_connection(addr, timeout=5) as s:
                try:
                    assert s.recv(1) == b""
                except ConnectionResetError:
                    pass


@pytest.mark.parametrize("mode", MODES)
def test_uplink_rate_limit(echo_server: EchoServer, mode: str) -> None:
    rate_mbit, size = 10.0, 1 << 20
    with emulated_link(_profile(up=rate_mbit), _target(echo_server), mode=mode) as addr:
        with _open(addr) as s:
            t = time.perf_counter()
            sender = threading.Thread(target=s.sendall, args=(bytes(size),))
            sender.start()
            recv_exact(s, size)
            elapsed = time.perf_counter() - t
            sender.join(timeout=10)
    expected = size * 8 / (rate_mbit * 1e6)
    assert elapsed >= 0.7 * expected  # token bucket bursts may run slightly ahead
    assert elapsed < expected + 5.0


def test_auto_falls_back_to_userspace(
    echo_server: EchoServer, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    no_netns = netns_mod.Capabilities(False, False, False, "simulated: no namespaces")
    monkeypatch.setattr(netns_mod, "detect_capabilities", lambda refresh=False: no_netns)
    caplog.set_level(logging.WARNING, logger="linkemu")
    emu = LinkEmulator(_profile(delay=2), _target(echo_server))
    with emu as addr, _open(addr) as s:
        s.sendall(b"ok")
        assert recv_exact(s, 2) == b"ok"
    assert emu.mode == "userspace"
    assert "falling back to the userspace relay" in caplog.text
    with pytest.raises(RuntimeError, match="netns mode unavailable"):
        LinkEmulator(_profile(delay=2), _target(echo_server), mode="netns").start()


# -- kernel path: clean-up ---------------------------------------------------------------------


def _ip_netns_list(pid: int | None = None) -> set[str]:
    """This process's (or ``pid``'s) emulator namespaces, as ``ip netns list`` shows them: other sessions on the
    machine may run emulators at the same time, so the machine-wide list is no baseline."""
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=True)
    prefix = f"{netns_mod.NS_PREFIX}-{os.getpid() if pid is None else pid}-"
    names = {line.split()[0] for line in out.stdout.splitlines() if line.strip()}
    return {name for name in names if name.startswith(prefix)}


@needs_netns
def test_netns_mode_builds_and_removes_everything(echo_server: EchoServer) -> None:
    before = _ip_netns_list()
    emu = LinkEmulator(PROFILES["5g"], _target(echo_server), mode="netns")
    with emu as addr:
        assert emu.mode == "netns" and emu.kernel_rate
        assert emu.kernel_loss == CAPS.nft
        created = _ip_netns_list() - before
        assert len(created) == 2
        ns = next(n for n in created if n.endswith("-c"))
        qdiscs = subprocess.run(["tc", "-n", ns, "qdisc", "show"], capture_output=True, text=True, check=True).stdout
        assert "tbf" in qdiscs
        with _open(addr) as s:
            s.sendall(b"x")
            assert recv_exact(s, 1) == b"x"
    assert _ip_netns_list() == before


@pytest.mark.skipif(not CAPS.nft, reason=f"nftables unavailable: {CAPS.reason or 'no netns'}")
def test_netns_loss_drops_real_packets(echo_server: EchoServer) -> None:
    emu = LinkEmulator(_profile(loss=5.0), _target(echo_server), mode="netns", seed=3)
    payload = random.Random(5).randbytes(1 << 20)
    with emu as addr, _open(addr) as s:
        sender = threading.Thread(target=s.sendall, args=(payload,))
        sender.start()
        assert recv_exact(s, len(payload)) == payload  # TCP recovered every drop
        sender.join(timeout=30)
        stats = emu.loss_stats()
    for lost, packets in stats.values():
        assert packets > 500
        assert 0.01 * packets < lost < 0.12 * packets  # 5 % configured, generous bounds


@needs_netns
def test_two_links_side_by_side(echo_server: EchoServer) -> None:
    # Benchmarks may compare links concurrently: each emulator has its own namespaces.
    before = _ip_netns_list()
    with (
        emulated_link(_profile(delay=30), _target(echo_server), mode="netns") as slow,
        emulated_link(_profile(delay=2), _target(echo_server), mode="netns") as fast,
    ):
        assert len(_ip_netns_list() - before) == 4
        timings = {}
        for name, addr in (("slow", slow), ("fast", fast)):
            with _open(addr) as s:
                s.sendall(b"warm")
                recv_exact(s, 4)
                rtts = []
                for _ in range(5):  # the quickest of five: one ping on a busy machine can wait for a core
                    t = time.perf_counter()
                    s.sendall(b"ping")
                    assert recv_exact(s, 4) == b"ping"
                    rtts.append(time.perf_counter() - t)
                timings[name] = min(rtts)
    assert timings["slow"] >= 0.060 - EARLY_TOLERANCE_S
    assert timings["fast"] < timings["slow"]
    assert _ip_netns_list() == before


@needs_netns
def test_netns_removed_after_exception(echo_server: EchoServer) -> None:
    before = _ip_netns_list()
    with pytest.raises(RuntimeError, match="boom"):
        with emulated_link(PROFILES["wifi"], _target(echo_server), mode="netns") as addr:
            s = _open(addr)  # left open on purpose: teardown must not wait for it
            raise RuntimeError("boom")
    s.close()
    assert _ip_netns_list() == before


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # what `sh -c 'cmd &'` hands its background jobs


@needs_netns
@pytest.mark.parametrize("inherited", ["default", "sigint-ignored"])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_cli_cleans_up_on_signal(echo_server: EchoServer, sig: signal.Signals, inherited: str) -> None:
    host, port = _target(echo_server)
    with subprocess.Popen(
        [sys.executable, "-m", "bench.linkemu", "--profile", "5g", "--target", f"{host}:{port}"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_ignore_sigint if inherited == "sigint-ignored" else None,
    ) as proc:
        try:
            assert proc.stdout is not None and proc.stderr is not None
            line = proc.stdout.readline()  # printed once the link is up
            assert "listening on" in line, proc.stderr.read() if proc.stderr else line
            assert len(_ip_netns_list(proc.pid)) == 2
            proc.send_signal(sig)
            assert proc.wait(timeout=15) == 0
            assert f"stopped by {sig.name}" in proc.stderr.read()
        finally:
            if proc.poll() is None:
                proc.kill()
    assert _ip_netns_list(proc.pid) == set()


@needs_netns
def test_cli_signal_during_set_up_still_cleans_up(echo_server: EchoServer) -> None:
    # Sent before the link is up: the signal waits until the namespaces exist, then they are deleted.
    host, port = _target(echo_server)
    with subprocess.Popen(
        [sys.executable, "-m", "bench.linkemu", "--profile", "5g", "--target", f"{host}:{port}"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as proc:
        try:
            deadline = time.monotonic() + 15
            while not _ip_netns_list(proc.pid) and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.001)  # poll until set-up has begun, then interrupt it
            proc.send_signal(signal.SIGINT)
            assert proc.wait(timeout=15) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
    assert _ip_netns_list(proc.pid) == set()


@needs_netns
def test_stale_namespaces_of_dead_processes_are_swept() -> None:
    pid = 4_000_000  # above the default pid_max, so never a live process
    while True:
        try:
            os.kill(pid, 0)
            pid += 1
        except ProcessLookupError:
            break
    name = f"{netns_mod.NS_PREFIX}-{pid}-1-c"
    subprocess.run(["ip", "netns", "add", name], check=True)
    try:
        assert name in netns_mod.sweep_stale()
        assert name not in list_namespaces()
    finally:
        subprocess.run(["ip", "netns", "del", name], capture_output=True, check=False)
