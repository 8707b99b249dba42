"""The client's routing policy over several netapps and a local fallback (pure: no network, the clock passed in)."""

from __future__ import annotations

import pytest

from netapp.client.policy import CONNECTED, FALLBACK, HEDGING, RECONNECTING, Mode, Policy, Route

S = 1_000_000_000  # one second in ns


def both_up(policy: Policy) -> Policy:
    for i in range(len(policy.health)):
        policy.up(i)
    return policy


def test_primary_fails_over_on_misses_and_probes_its_way_back() -> None:
    p = both_up(Policy("primary", 2, miss_limit=2, probe_interval_s=1.0))
    assert p.route(0) == Route((0,)) and p.mode() == Mode(CONNECTED, (0,), False)
    p.outcome(0, on_time=False)
    assert p.route(0) == Route((0,))  # one miss is not a failure
    p.outcome(0, on_time=False)
    assert p.route(1 * S) == Route((1,), probes=(0,))  # failed over; the first netapp gets a probe
    assert p.route(1 * S + 1) == Route((1,))  # the next probe waits its interval
    assert p.route(2 * S + 1).probes == (0,)
    p.outcome(0, on_time=True)  # the probe came back in time: back to the first netapp
    assert p.route(3 * S) == Route((0,))


def test_primary_fails_over_when_its_netapp_is_down_and_back_when_it_is_up() -> None:
    p = both_up(Policy("primary", 2))
    p.down(0)
    assert p.route(0) == Route((1,))  # a netapp that is down gets no probes: its transport reconnects
    p.up(0)
    assert p.route(0) == Route((0,))


def test_nobody_on_time_goes_to_every_live_netapp_and_the_fallback() -> None:
    p = both_up(Policy("primary", 2, fallback=True, miss_limit=1))
    p.outcome(0, False)
    p.outcome(1, False)
    assert p.mode() == Mode(FALLBACK, (0, 1), True)
    assert p.route(0) == Route((0, 1), local=True)
    p.outcome(1, True)  # a netapp answers in time again: the fallback stops at once
    assert p.route(0) == Route((1,), probes=(0,))
    p.down(0)
    p.down(1)
    assert p.mode() == Mode(FALLBACK, (), True)
    without = Policy("primary", 1)
    assert without.mode() == Mode(RECONNECTING, (), False)  # not connected yet, no fallback


def test_hedge_sends_to_every_live_netapp() -> None:
    p = both_up(Policy("hedge", 3))
    assert p.route(0) == Route((0, 1, 2)) and p.mode().state == HEDGING
    p.down(1)
    assert p.route(0) == Route((0, 2))
    p.down(2)
    assert p.mode() == Mode(CONNECTED, (0,), False)


def test_adaptive_hedges_from_the_first_miss_until_the_primary_recovers() -> None:
    p = both_up(Policy("adaptive", 2, recover_after=3))
    assert p.route(0) == Route((0,))
    p.outcome(0, False)
    assert p.route(0) == Route((0, 1)) and p.mode().state == HEDGING
    p.outcome(0, True)
    p.outcome(0, True)
    assert p.route(0) == Route((0, 1))  # two on time of three: still hedging
    p.outcome(0, True)
    assert p.route(0) == Route((0,))
    p.down(0)
    assert p.route(0) == Route((1,))
    p.up(0)
    assert p.route(0) == Route((0, 1))  # back, but it has to prove itself first


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="primary, hedge, adaptive"):
        Policy("fastest", 2)
    with pytest.raises(ValueError, match="at least one netapp"):
        Policy("primary", 0)


def test_a_move_hedges_old_and_new_until_the_new_one_is_on_time_then_retires_the_old() -> None:
    p = Policy("primary", 1, recover_after=2, move_timeout_s=10.0)
    p.up(0)
    new = p.add()
    p.begin_move(0, new, now_ns=0)
    assert p.route(0) == Route((0,)) and p.moving  # the new one is not up yet: the old one serves alone
    p.up(new)
    assert p.mode() == Mode(HEDGING, (0, 1), False)  # every frame to both
    p.outcome(new, on_time=True)
    assert p.mode().netapps == (0, 1) and p.retired() == []
    p.outcome(new, on_time=True)  # on time twice in a row: the old one is left behind, once
    assert p.mode() == Mode(CONNECTED, (1,), False) and p.retired() == [0] and p.retired() == []
    assert not p.moving and p.first == 1
    p.up(0)  # a late reconnect of the old one does not bring it back
    assert p.route(S) == Route((1,))
    # The next move takes the retired slot back into service.
    p.down(0)
    p.begin_move(1, 0, now_ns=S)
    p.up(0)
    assert p.mode().netapps == (0, 1)


def test_a_move_that_does_not_get_there_in_time_ends() -> None:
    p = both_up(Policy("primary", 2, move_timeout_s=1.0))
    p.begin_move(0, 1, now_ns=0)
    assert p.route(S // 2).netapps == (0, 1)
    assert p.route(2 * S) == Route((1,)) and p.retired() == [0]  # the new one is up: the old one goes
    p = both_up(Policy("primary", 2, move_timeout_s=1.0))
    p.down(1)
    p.begin_move(0, 1, now_ns=0)
    assert p.route(2 * S) == Route((0,)) and p.retired() == [] and not p.moving  # not up: the move is given up


def test_an_idle_move_finishes_once_the_new_one_is_up() -> None:
    p = both_up(Policy("primary", 2))
    p.down(1)
    p.begin_move(0, 1, now_ns=0)
    p.finish_move()
    assert p.moving and p.retired() == []  # the new one is not up: nothing changes
    p.up(1)
    p.finish_move()
    assert not p.moving and p.retired() == [0] and p.route(0) == Route((1,))
