"""Links that change during a run: the schedule's pure functions, then outages and delay, loss and rate changes through
a real relay in front of a real TCP echo server (both modes; short, with deadlines)."""

from __future__ import annotations

import random
import socket
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass

import pytest

from bench.linkemu import (
    Change,
    LinkEmulator,
    LinkProfile,
    LinkSchedule,
    Outages,
    detect_capabilities,
    parse_change,
    parse_outages,
    parse_trace,
    read_trace,
)
from bench.linkemu.relay import DirectionModel
from tests.support.echo import EchoServer, recv_exact
from tests.support.echo import open_echo as _open
from tests.support.paths import ROOT

pytestmark = pytest.mark.timeout(60)

CAPS = detect_capabilities()
needs_nft = pytest.mark.skipif(not CAPS.nft, reason=f"kernel loss unavailable: {CAPS.reason or 'no netns'}")
MODES = [pytest.param("netns", marks=needs_nft), "userspace"]
BASE = LinkProfile("t", 5.0, 0.0, 0.0, None, None)


# -- pure ------------------------------------------------------------------------------------------------------------


def test_outages_windows_and_edges() -> None:
    o = Outages(down_s=3, every_s=20)
    assert o.window(0) is None and o.window(19.99) is None  # a run starts on a working link
    assert o.window(20) == (20, 23) and o.window(22.9) == (20, 23) and o.window(23) is None
    assert o.window(41) == (40, 43)
    assert o.windows(60) == [(20, 23), (40, 43)]
    edges = o.edges()
    assert [next(edges) for _ in range(4)] == [20, 23, 40, 43]
    assert Outages(1, 10, first_s=0).window(0.5) == (0, 1)
    for bad in ((0, 10), (10, 10), (-1, 10)):
        with pytest.raises(ValueError):
            Outages(*bad)


def test_schedule_applies_changes_in_order() -> None:
    s = LinkSchedule(changes=(Change(30, delay_ms=150), Change(10, loss_pct=1.0)), outages=Outages(3, 20))
    assert s.profile_at(BASE, 5) == BASE
    assert s.profile_at(BASE, 10).loss_pct == 1.0 and s.profile_at(BASE, 10).delay_ms == 5.0
    at_40 = s.state_at(BASE, 40)
    assert (at_40.profile.delay_ms, at_40.profile.loss_pct, at_40.down_until) == (150, 1.0, 43)
    assert not s.state_at(BASE, 43).down
    edges = s.edges()
    assert [next(edges) for _ in range(6)] == [10, 20, 23, 30, 40, 43]
    assert list(LinkSchedule(changes=(Change(1, delay_ms=2),)).edges()) == [1]
    assert LinkSchedule().is_static and not s.is_static
    with pytest.raises(ValueError):  # a change yields a profile that is checked like any other
        LinkSchedule(changes=(Change(1, loss_pct=100),)).profile_at(BASE, 2)


def test_parse_outages_and_changes() -> None:
    assert parse_outages("3/20") == Outages(3, 20)
    assert parse_outages("0.5/4+1") == Outages(0.5, 4, 1)
    assert parse_change("30:delay=150") == Change(30, delay_ms=150)
    assert parse_change("2.5:loss=1,jitter=3") == Change(2.5, jitter_ms=3, loss_pct=1)
    for bad in ("3", "x/20", "20/3"):
        with pytest.raises(ValueError, match="DOWN/EVERY"):
            parse_outages(bad)
    assert parse_change("20:up=1.5") == Change(20, up_mbit=1.5)
    assert parse_change("0:up=2,down=30,delay=40") == Change(0, delay_ms=40, up_mbit=2, down_mbit=30)
    for bad in ("30", "30:rate=1", "x:delay=1", "30:delay=fast"):
        with pytest.raises(ValueError, match="T:delay=MS"):
            parse_change(bad)
    with pytest.raises(ValueError):  # a rate of 0 is refused like any profile's, when the change is applied
        LinkSchedule(changes=(parse_change("1:up=0"),)).profile_at(BASE, 2)


def test_rate_changes_apply_per_direction() -> None:
    shaped = LinkProfile("t", 5.0, 0.0, 0.0, 20.0, 50.0)
    s = LinkSchedule(changes=(Change(10, up_mbit=1.5), Change(20, down_mbit=5), Change(30, up_mbit=15.6)))
    rates = [(p.rate_mbit_up, p.rate_mbit_down) for p in (s.profile_at(shaped, t) for t in (0, 10, 20, 30))]
    assert rates == [(20.0, 50.0), (1.5, 50.0), (1.5, 5.0), (15.6, 5.0)]


def test_a_rate_trace_parses_to_changes_and_refuses_bad_rows(tmp_path) -> None:
    text = "# time up down (published-style trace)\n0 15.6 50\n20, 1.5, -   # the cell edge\n\n40\t15.6\t-\n"
    assert parse_trace(text) == (
        Change(0, up_mbit=15.6, down_mbit=50),
        Change(20, up_mbit=1.5),
        Change(40, up_mbit=15.6),
    )
    for bad, says in [
        ("", "no rows"),
        ("0 1", "line 1: expected TIME UP DOWN"),
        ("0 1 1\n0 2 2", "line 2"),  # times must increase
        ("0 0 1", "over 0 Mbit/s"),
        ("- 1 1", "time cannot be -"),
        ("0 fast 1", "line 1"),
    ]:
        with pytest.raises(ValueError, match=says):
            parse_trace(bad)
    path = tmp_path / "trace.txt"
    path.write_text(text)
    assert read_trace(str(path)) == parse_trace(text)
    with pytest.raises(ValueError, match="cannot read the trace"):
        read_trace(str(tmp_path / "missing.txt"))
    path.write_bytes(b"0 1 1\n" * 800_000)  # over 4 MiB: refused before it is parsed
    with pytest.raises(ValueError, match="over 4 MiB"):
        read_trace(str(path))


def test_direction_model_holds_chunks_while_down() -> None:
    m = DirectionModel(0.010, down_until=5.0)
    assert m.release_time(3.0, 100) == pytest.approx(5.010)  # sent during the outage: arrives after it
    assert m.release_time(6.0, 100) == pytest.approx(6.010)


def test_cli_rejects_a_bad_trace(tmp_path) -> None:
    trace = tmp_path / "t.txt"
    trace.write_text("0 1 1\n0 2 2\n")
    out = subprocess.run(
        [sys.executable, "-m", "bench.linkemu", "--profile", "5g", "--target", "127.0.0.1:1", "--trace", str(trace)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 2 and "--trace" in out.stderr and "line 2" in out.stderr


def test_cli_rejects_a_bad_schedule() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "bench.linkemu", "--profile", "5g", "--target", "127.0.0.1:1", "--outage", "20/3"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 2 and "--outage" in out.stderr and "less than its period" in out.stderr


# -- through the relay -----------------------------------------------------------------------------------------------


@dataclass
class Ping:
    sent: float  # on the link's clock (LinkEmulator.elapsed)
    received: float


def _ping_until(emu: LinkEmulator, addr: tuple[str, int], until: float) -> list[Ping]:
    """Echo small messages one after the other on one connection until the link's clock reaches ``until``."""
    pings: list[Ping] = []
    with _open(addr) as s:
        s.settimeout(20)
        i = 0
        while emu.elapsed() < until:
            msg = f"ping {i:05d}".encode()
            sent = emu.elapsed()
            s.sendall(msg)
            assert recv_exact(s, len(msg)) == msg  # nothing lost or reordered across the outage
            pings.append(Ping(sent, emu.elapsed()))
            i += 1
    return pings


@pytest.mark.parametrize("mode", MODES)
def test_outage_stops_the_link_and_it_comes_back(echo_server: EchoServer, mode: str) -> None:
    outage = Outages(down_s=0.6, every_s=100, first_s=0.4)
    emu = LinkEmulator(BASE, echo_server.target, mode=mode, schedule=LinkSchedule(outages=outage))
    with emu as addr:
        pings = _ping_until(emu, addr, until=2.5)
        assert not emu.state.down
    start, end = 0.4, 1.0
    settle = 0.05  # netns: the nft rule is replaced by a subprocess, a few ms after the edge
    # Nothing gets through while the link is down; the ping in flight is answered only once it is back (netns: at
    # TCP's next retransmission).
    assert not [p for p in pings if start + settle <= p.received < end - 0.002]
    assert [p for p in pings if p.sent < start + settle and p.received >= end - 0.002], "no ping waited for the link"
    before = [p for p in pings if p.received < start]
    assert len(before) > 5 and statistics.median(p.received - p.sent for p in before) < 0.2
    after = [p for p in pings if p.sent > end]
    assert len(after) > 5, "the link did not come back"
    assert statistics.median(p.received - p.sent for p in after) < 0.2


@pytest.mark.parametrize("mode", MODES)
def test_delay_changes_mid_run(echo_server: EchoServer, mode: str) -> None:
    schedule = LinkSchedule(changes=(Change(0.5, delay_ms=40),))
    emu = LinkEmulator(BASE, echo_server.target, mode=mode, schedule=schedule)
    with emu as addr:
        pings = _ping_until(emu, addr, until=1.2)
        assert emu.state.profile.delay_ms == 40
    rtts_before = [p.received - p.sent for p in pings if p.received < 0.5]
    rtts_after = [p.received - p.sent for p in pings if p.sent > 0.55]
    assert rtts_before and min(rtts_before) >= 0.010 - 0.002 and statistics.median(rtts_before) < 0.060
    assert rtts_after and min(rtts_after) >= 0.080 - 0.002


def _bulk_seconds(addr: tuple[str, int], size: int) -> float:
    """Send ``size`` bytes through the link and read them back; the seconds it took."""
    with _open(addr) as s:
        s.settimeout(20)
        t = time.perf_counter()
        sender = threading.Thread(target=s.sendall, args=(bytes(size),))
        sender.start()
        recv_exact(s, size)
        sender.join(timeout=10)
        return time.perf_counter() - t


@pytest.mark.parametrize("mode", MODES)
def test_uplink_rate_changes_mid_run(echo_server: EchoServer, mode: str) -> None:
    # 20 Mbit/s up, then 2 Mbit/s from t=0.6 s: the same transfer takes about ten times as long after the step.
    size, fast, slow = 200_000, 20.0, 2.0
    schedule = LinkSchedule(changes=(Change(0.6, up_mbit=slow),))
    emu = LinkEmulator(LinkProfile("t", 2.0, 0.0, 0.0, fast, None), echo_server.target, mode=mode, schedule=schedule)
    with emu as addr:
        before = _bulk_seconds(addr, size)
        assert emu.elapsed() < 0.6, "the first transfer should end before the step (a very slow machine?)"
        while emu.elapsed() < 0.7:
            time.sleep(0.01)  # waiting for the link's clock to pass the step, not for a thread
        assert emu.state.profile.rate_mbit_up == slow
        after = _bulk_seconds(addr, size)
    slow_s = size * 8 / (slow * 1e6)
    assert after >= 0.7 * slow_s  # token bucket bursts may run slightly ahead
    assert before < 0.5 * after


@needs_nft
def test_loss_changes_mid_run_in_the_kernel(echo_server: EchoServer) -> None:
    schedule = LinkSchedule(changes=(Change(0.3, loss_pct=5.0),))
    emu = LinkEmulator(BASE, echo_server.target, mode="netns", schedule=schedule, seed=3)
    payload = random.Random(5).randbytes(1 << 20)
    with emu as addr:
        assert emu.kernel_loss
        assert all(lost == 0 for lost, _ in emu.loss_stats().values())
        deadline = time.monotonic() + 10
        while emu.state.profile.loss_pct != 5.0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emu.state.profile.loss_pct == 5.0
        with _open(addr) as s:
            sender = threading.Thread(target=s.sendall, args=(payload,))
            sender.start()
            assert recv_exact(s, len(payload)) == payload
            sender.join(timeout=30)
        stats = emu.loss_stats()
    for lost, packets in stats.values():
        assert 0.01 * packets < lost < 0.12 * packets


@pytest.mark.parametrize("mode", MODES)
def test_two_links_one_down_the_other_up(echo_server: EchoServer, mode: str) -> None:
    # A robot with two carriers: while one is down the other still answers in its own time.
    down = LinkEmulator(BASE, echo_server.target, mode=mode, schedule=LinkSchedule(outages=Outages(5, 100, 0)))
    with down as down_addr, LinkEmulator(BASE, echo_server.target, mode=mode) as up_addr:
        with _open(down_addr) as stuck:
            stuck.sendall(b"lost?")
            stuck.settimeout(0.5)
            with pytest.raises(socket.timeout):
                stuck.recv(5)  # the outage lasts 5 s; 0.5 s of silence is enough to see it
            assert down.state.down
            with _open(up_addr) as s:
                s.sendall(b"alive")
                assert recv_exact(s, 5) == b"alive"


@pytest.mark.parametrize("mode", MODES)
def test_a_held_schedule_starts_when_asked(echo_server: EchoServer, mode: str) -> None:
    # A benchmark starts the schedule once its robot streams, however long the robot took to get ready.
    schedule = LinkSchedule(changes=(Change(0.0, delay_ms=40),))
    emu = LinkEmulator(BASE, echo_server.target, mode=mode, schedule=schedule, hold_schedule=True)
    with emu as addr, _open(addr) as s:
        s.sendall(b"warm")
        recv_exact(s, 4)
        assert _quickest_rtt(s) < 0.060 and emu.started_at is None  # held: the profile as given
        emu.start_schedule()
        deadline = time.monotonic() + 10
        while emu.state.profile.delay_ms != 40 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert _quickest_rtt(s) >= 0.080 - 0.002
        assert emu.elapsed() < 5


def _quickest_rtt(s: socket.socket, count: int = 5) -> float:
    """The quickest of a few echoes: one alone on a busy machine can wait for a core."""
    rtts = []
    for _ in range(count):
        t = time.perf_counter()
        s.sendall(b"ping")
        assert recv_exact(s, 4) == b"ping"
        rtts.append(time.perf_counter() - t)
    return min(rtts)
