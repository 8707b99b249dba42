"""Deploying ahead (pure): a route is bounded and checked, its pools are readied ahead and the robot moved on time,
never flapping; warm standbys wait on each robot's next-best placement and go after an idle grace."""

from __future__ import annotations

import pytest
from netapp_middleware.switchover.ahead import (
    AheadPolicy,
    RouteRefused,
    Waypoint,
    check_route,
    next_best,
    plan_route,
    route_record,
    route_recorded,
    standby_needs,
    warm_plan,
)

POLICY = AheadPolicy(max_waypoints=4, horizon_s=600, min_dwell_s=5, warm_lead_s=30, switch_lead_s=0.5)
POOLS = ["edge", "cloud", "fog"]
NOW = 1000.0


def test_a_good_route_is_taken_as_waypoints() -> None:
    assert check_route([("cloud", NOW + 10), ("fog", NOW + 20)], NOW, POOLS, POLICY) == (
        Waypoint("cloud", NOW + 10),
        Waypoint("fog", NOW + 20),
    )
    assert check_route([], NOW, POOLS, POLICY) == ()
    assert check_route([("cloud", NOW - 0.5)], NOW, POOLS, POLICY)  # a clock a little behind is fine


@pytest.mark.parametrize(
    ("route", "says"),
    [
        ([("mars", NOW + 10)], "unknown pool 'mars': the middleware serves edge, cloud, fog"),
        ([("cloud", NOW - 5)], "the eta of cloud is 5.0 s in the past"),
        ([("cloud", NOW + 601)], "more than 600 s ahead"),
        ([("cloud", float("nan"))], "in the past"),
        ([("cloud", NOW + 10 * i + 10) for i in range(5)], "at most 4 waypoints, got 5"),
        ([("cloud", NOW + 20), ("fog", NOW + 10)], "etas must increase"),
        ([("cloud", NOW + 10), ("cloud", NOW + 20)], "cloud follows itself"),
        ([("cloud", NOW + 10), ("edge", NOW + 11), ("cloud", NOW + 12)], "flapping: cloud then edge 1.0 s later"),
    ],
)
def test_a_bad_route_is_refused_with_one_line(route: list[tuple[str, float]], says: str) -> None:
    with pytest.raises(RouteRefused, match=None) as refused:
        check_route(route, NOW, POOLS, POLICY)
    assert says in str(refused.value) and "\n" not in str(refused.value)


def test_pools_are_readied_ahead_and_the_robot_moved_just_before_its_eta() -> None:
    route = (Waypoint("cloud", NOW + 40), Waypoint("fog", NOW + 100))
    far = plan_route(route, NOW, "edge", arrived_at=0.0, policy=POLICY)
    assert (far.warm, far.move_to, far.route) == ((), None, route)  # nothing within the 30 s lead yet
    ahead = plan_route(route, NOW + 15, "edge", 0.0, POLICY)
    assert (ahead.warm, ahead.move_to) == (("cloud",), None)  # cloud readied 25 s before the robot gets there
    due = plan_route(route, NOW + 39.6, "edge", 0.0, POLICY)
    assert (due.warm, due.move_to) == (("cloud",), "cloud")  # moved 0.5 s ahead of the eta
    there = plan_route(route, NOW + 75, "cloud", NOW + 40, POLICY)
    assert (there.warm, there.move_to, there.route) == (("fog",), None, route)
    # Past the fog's eta the cloud waypoint is behind the robot: dropped, and nothing readied for it any more.
    past = plan_route(route, NOW + 101, "cloud", NOW + 40, POLICY)
    assert (past.warm, past.move_to, past.route) == (("fog",), "fog", (route[1],))


def test_no_move_sooner_than_the_minimum_dwell_after_arriving() -> None:
    route = (Waypoint("cloud", NOW + 1),)
    assert plan_route(route, NOW + 1, "edge", arrived_at=NOW - 2, policy=POLICY).move_to is None
    assert plan_route(route, NOW + 3, "edge", arrived_at=NOW - 2, policy=POLICY).move_to == "cloud"


def test_a_standby_waits_on_each_robots_next_best_placement() -> None:
    assert next_best("edge", ["edge", "cloud"]) == "cloud" and next_best("cloud", ["edge", "cloud"]) == "edge"
    robots = [("detect", "edge"), ("detect", "edge"), ("track", "edge"), ("other", "edge"), ("fixed", "cloud")]
    wanted = {"detect": "nextBest", "track": "nextBest", "fixed": "cloud"}
    # Shared: two detect robots on edge need one standby; a robot already on the standby's placement needs none.
    assert standby_needs(robots, wanted, ["edge", "cloud"]) == {("detect", "cloud"), ("track", "cloud")}


def test_warm_netapps_start_when_needed_and_go_after_the_idle_grace() -> None:
    key = ("detect", "cloud")
    start = warm_plan({key}, [], {}, NOW, grace_s=10)
    assert (start.start, start.release, start.idle_since) == ({key}, set(), {})
    idle = warm_plan(set(), [key], {}, NOW, grace_s=10)
    assert (idle.start, idle.release, idle.idle_since) == (set(), set(), {key: NOW})
    assert warm_plan(set(), [key], idle.idle_since, NOW + 9, 10).release == set()
    assert warm_plan(set(), [key], idle.idle_since, NOW + 10, 10).release == {key}
    # Needed again within the grace: kept, and its idle clock starts afresh next time.
    assert warm_plan({key}, [key], idle.idle_since, NOW + 5, 10) == warm_plan({key}, [key], {}, NOW + 5, 10)


def test_the_policy_refuses_nonsense() -> None:
    with pytest.raises(ValueError):
        AheadPolicy(max_waypoints=0)
    with pytest.raises(ValueError):
        AheadPolicy(min_dwell_s=-1)


def test_a_recorded_route_comes_back_with_its_waypoints_still_ahead_and_nothing_else() -> None:
    route = (Waypoint("cloud", NOW - 5), Waypoint("fog", NOW + 20))
    record = route_record(route)
    assert record == [["cloud", NOW - 5], ["fog", NOW + 20]]
    assert route_recorded(record, NOW, POOLS, POLICY) == (Waypoint("fog", NOW + 20),)  # the passed one is behind
    for bad in (None, "cloud", [["mars", NOW + 20]], [["fog"]], [["fog", "soon"]], [["fog", float("nan")]]):
        assert route_recorded(bad, NOW, POOLS, POLICY) == ()
    assert route_recorded([["fog", NOW + 20]] * 5, NOW, POOLS, POLICY) == ()  # over max_waypoints
