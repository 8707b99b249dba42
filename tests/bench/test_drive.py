"""The drive through pools: each pool's link schedule (pure), the share of frames within budget (pure), and the
per-pool links in front of a real TCP echo server (their figures follow the schedule, on one clock)."""

from __future__ import annotations

import pytest

from bench.drive import POOLS, drive_schedules, within_budget
from bench.linkemu import Change, LinkProfile, LinkSchedule
from bench.linkemu.pools import PoolLinks
from tests.support.echo import EchoServer, open_echo, recv_exact
from tests.support.polling import wait_until

pytestmark = pytest.mark.timeout(60)


def test_each_pool_is_near_in_its_own_leg_and_the_cells_overlap() -> None:
    links = PoolLinks(drive_schedules(POOLS, leg_s=10.0, overlap_s=1.0, near_ms=10.0, far_ms=150.0))
    near = {t: [p for p in POOLS if links.delay_ms(p, t) == 10.0] for t in (0.0, 5.0, 9.5, 11.5, 15.0, 20.5, 29.0)}
    assert near == {
        0.0: ["pool-a"],
        5.0: ["pool-a"],
        9.5: ["pool-a", "pool-b"],  # the cells overlap: the move is made while both are near
        11.5: ["pool-b"],
        15.0: ["pool-b"],
        20.5: ["pool-b", "pool-c"],
        29.0: ["pool-c"],
    }
    assert links.delay_ms("pool-a", 11.5) == 150.0 and links.delay_ms("elsewhere", 0.0) == 0.0
    with pytest.raises(ValueError, match="overlap"):
        drive_schedules(POOLS, leg_s=10.0, overlap_s=5.0, near_ms=10.0, far_ms=150.0)


def test_a_frame_without_a_result_is_not_within_budget() -> None:
    assert within_budget({1: 50.0, 2: 150.0, 3: 151.0}, [1, 2, 3, 4], 150.0) == (2, 1)


def test_a_pools_netapps_are_reached_through_its_link_which_follows_the_schedule(echo_server: EchoServer) -> None:
    host, port = echo_server.target
    url = f"http://{host}:{port}"
    base = LinkProfile("pool-a", 1.0, 0.0, 0.0, None, None)
    links = PoolLinks({"pool-a": (base, LinkSchedule(changes=(Change(0.05, delay_ms=40.0),)))})
    try:
        linked = links.url_for("pool-a", url)
        assert linked != url and links.url_for("pool-a", url) == linked  # one link per netapp
        assert links.url_for("pool-b", url) == url  # a pool without a link is reached directly
        link_host, link_port = linked.removeprefix("http://").split(":")
        with open_echo((link_host, int(link_port))) as sock:
            sock.sendall(b"hello")
            assert recv_exact(sock, 5) == b"hello"
        (link,) = links.links.values()
        assert link.state.profile.delay_ms == 1.0  # held until the schedules start
        links.start_schedules()
        wait_until(lambda: link.state.profile.delay_ms == 40.0, what="the scheduled change")
    finally:
        links.close()
    assert links.links == {}
