"""Pure placement: pool health from nodes, policies, GPU, failover after the grace period."""

from __future__ import annotations

import datetime

from netapp_operator.placement import Pool, build_pools, choose_pool, choose_standby, decide
from netapp_operator.spec import parse

from tests.operator.op_helpers import node, nodepool

NOW = datetime.datetime(2026, 1, 1, 12, 0, tzinfo=datetime.timezone.utc)


def pools(*specs: tuple, nodes: list) -> dict[str, Pool]:
    return build_pools([nodepool(*s[:3], **(s[3] if len(s) > 3 else {})) for s in specs], nodes)


def spec(**kw):
    kw.setdefault("image", "img")
    return parse(kw)


def test_pool_health_counts_ready_schedulable_matching_nodes():
    cordoned = node("e3", {"pool": "e"})
    cordoned["spec"] = {"unschedulable": True}
    ps = pools(
        ("e", "edge", {"pool": "e"}),
        nodes=[
            node("e1", {"pool": "e"}, address="1.1.1.1"),
            node("e2", {"pool": "e"}, ready=False),
            cordoned,
            node("c1", {"pool": "c"}),
        ],
    )
    assert (ps["e"].ready_nodes, ps["e"].total_nodes, ps["e"].addresses) == (1, 3, ("1.1.1.1",))


def test_auto_prefers_highest_priority_edge_then_cloud():
    nodes = [node("a", {"p": "a"}), node("b", {"p": "b"}), node("c", {"p": "c"})]
    ps = pools(
        ("low", "edge", {"p": "a"}, {"priority": 1}),
        ("high", "edge", {"p": "b"}, {"priority": 5}),
        ("cloud", "cloud", {"p": "c"}, {"priority": 100}),
        nodes=nodes,
    )
    assert choose_pool(spec(), ps).pool.name == "high"
    assert choose_pool(spec(), ps, exclude=["high", "low"]).pool.name == "cloud"
    assert choose_pool(spec(placement={"policy": "cloud"}), ps).pool.name == "cloud"


def test_auto_falls_back_to_cloud_when_no_edge_node_is_ready():
    ps = pools(
        ("edge", "edge", {"p": "e"}),
        ("cloud", "cloud", {"p": "c"}),
        nodes=[node("e", {"p": "e"}, ready=False), node("c", {"p": "c"})],
    )
    choice = choose_pool(spec(), ps)
    assert choice.pool.name == "cloud" and "fallback" in choice.message


def test_gpu_requirement_skips_pools_without_gpu():
    ps = pools(
        ("edge", "edge", {"p": "e"}),
        ("gpu", "cloud", {"p": "g"}, {"gpu": True}),
        nodes=[node("e", {"p": "e"}), node("g", {"p": "g"})],
    )
    assert choose_pool(spec(resources={"gpus": 1}), ps).pool.name == "gpu"
    assert choose_pool(spec(placement={"requireGPU": True}), ps).pool.name == "gpu"
    none = choose_pool(spec(placement={"policy": "edge", "requireGPU": True}), ps)
    assert none.pool is None and none.reason == "NoEligiblePool" and "GPU" in none.message


def test_named_pool_pins_and_unknown_pool_is_a_reason():
    ps = pools(("edge", "edge", {"p": "e"}), nodes=[node("e", {"p": "e"}, ready=False)])
    assert choose_pool(spec(placement={"pool": "edge"}), ps).pool.name == "edge"
    missing = choose_pool(spec(placement={"pool": "nope"}), ps)
    assert missing.pool is None and missing.reason == "PoolNotFound"


def test_failover_waits_for_the_grace_period_then_moves():
    ps = pools(
        ("edge", "edge", {"p": "e"}),
        ("cloud", "cloud", {"p": "c"}),
        nodes=[node("e", {"p": "e"}, ready=False), node("c", {"p": "c"})],
    )
    since = NOW - datetime.timedelta(seconds=10)
    wait = decide(spec(), "edge", ps, since, NOW, grace_seconds=30)
    assert (wait.action, wait.pool.name, wait.reason) == ("stay", "edge", "PoolUnavailable")
    move = decide(spec(), "edge", ps, NOW - datetime.timedelta(seconds=31), NOW, grace_seconds=30)
    assert (move.action, move.pool.name, move.reason) == ("move", "cloud", "FailedOver")
    first_seen = decide(spec(), "edge", ps, None, NOW, grace_seconds=30)
    assert first_seen.action == "stay" and first_seen.unhealthy_since == NOW


def test_healthy_pool_is_sticky_and_deleted_pool_moves_at_once():
    ps = pools(
        ("edge", "edge", {"p": "e"}, {"priority": 9}),
        ("cloud", "cloud", {"p": "c"}),
        nodes=[node("e", {"p": "e"}), node("c", {"p": "c"})],
    )
    assert decide(spec(), "cloud", ps, None, NOW, 30).action == "stay"  # no flapping back to edge
    gone = decide(spec(), "vanished", ps, None, NOW, 30)
    assert (gone.action, gone.pool.name) == ("move", "edge")


def test_a_pinned_netapp_never_fails_over():
    ps = pools(
        ("edge", "edge", {"p": "e"}),
        ("cloud", "cloud", {"p": "c"}),
        nodes=[node("e", {"p": "e"}, ready=False), node("c", {"p": "c"})],
    )
    d = decide(spec(placement={"pool": "edge"}), "edge", ps, NOW - datetime.timedelta(hours=1), NOW, 30)
    assert (d.action, d.pool.name, d.reason) == ("stay", "edge", "PoolPinned")


def test_no_failover_target_keeps_the_netapp_where_it_is():
    ps = pools(("edge", "edge", {"p": "e"}), nodes=[node("e", {"p": "e"}, ready=False)])
    d = decide(spec(), "edge", ps, NOW - datetime.timedelta(hours=1), NOW, 30)
    assert (d.action, d.reason) == ("stay", "NoFailoverTarget")


def test_policy_change_moves_the_netapp():
    ps = pools(
        ("edge", "edge", {"p": "e"}),
        ("cloud", "cloud", {"p": "c"}),
        nodes=[node("e", {"p": "e"}), node("c", {"p": "c"})],
    )
    d = decide(spec(placement={"policy": "cloud"}), "edge", ps, None, NOW, 30)
    assert (d.action, d.pool.name, d.reason) == ("move", "cloud", "PlacementChanged")


def test_a_standby_waits_on_the_next_best_pool_or_its_pinned_one():
    ps = pools(
        ("e1", "edge", {"pool": "e1"}, {"priority": 5}),
        ("e2", "edge", {"pool": "e2"}),
        ("c", "cloud", {"pool": "c"}),
        ("g", "cloud", {"pool": "g"}, {"gpu": True}),
        nodes=[node(n, {"pool": n}) for n in ("e1", "e2", "c", "g")],
    )
    assert choose_standby(spec(), ps["e1"], ps) is None  # none asked for
    assert choose_standby(spec(standby={}), ps["e1"], ps).name == "e2"  # the next-best: another edge pool first
    assert choose_standby(spec(standby={}, placement={"policy": "edge"}), ps["e2"], ps).name == "e1"
    gpu = spec(standby={}, placement={"requireGPU": True})
    assert choose_standby(gpu, ps["g"], ps) is None  # no other pool offers a GPU
    assert choose_standby(spec(standby={"pool": "c"}), ps["e1"], ps).name == "c"
    assert choose_standby(spec(standby={"pool": "e1"}), ps["e1"], ps) is None  # never on its own pool
    assert choose_standby(spec(standby={"pool": "nowhere"}), ps["e1"], ps) is None
