"""Pure status: Ready follows available replicas; conditions keep their transition times."""

from __future__ import annotations

import datetime

from netapp_operator import status

NOW = datetime.datetime(2026, 1, 1, 12, 0, tzinfo=datetime.timezone.utc)
LATER = NOW + datetime.timedelta(minutes=5)


def dep(replicas: int, available: int, ready: int | None = None, **extra) -> dict:
    return {
        "spec": {"replicas": replicas},
        "status": {"availableReplicas": available, "readyReplicas": available if ready is None else ready, **extra},
    }


def test_crash_looping_pods_are_never_ready():
    r = status.readiness(dep(2, 0, ready=0, unavailableReplicas=2), "http://x")
    assert not r.ready and r.reason == "ReplicasUnavailable" and r.message == "0/2 replicas available"
    assert not status.readiness(dep(2, 1), "http://x").ready
    assert status.readiness(dep(2, 2), "http://x").ready


def test_ready_needs_a_url_and_a_deployment():
    assert status.readiness(dep(1, 1), None).reason == "WaitingForAddress"
    assert status.readiness(None, "http://x").reason == "DeploymentMissing"


def test_progress_deadline_is_failed():
    d = dep(
        1,
        0,
        conditions=[
            {"type": "Progressing", "status": "False", "reason": "ProgressDeadlineExceeded", "message": "timed out"}
        ],
    )
    s = status.placed_status(
        {},
        pool="p",
        placed_reason="PoolSelected",
        placed_message="m",
        pool_available=True,
        pool_message="ok",
        deployment=d,
        url="http://x",
        generation=3,
        now=NOW,
    )
    assert s["phase"] == "Failed" and s["observedGeneration"] == 3


def test_transition_time_moves_only_when_status_flips():
    c1 = status.set_condition([], "Ready", False, "A", "a", NOW)
    c2 = status.set_condition(c1, "Ready", False, "B", "b", LATER)
    assert c2[0]["lastTransitionTime"] == status.timestamp(NOW) and c2[0]["reason"] == "B"
    c3 = status.set_condition(c2, "Ready", True, "C", "c", LATER)
    assert c3[0]["lastTransitionTime"] == status.timestamp(LATER)


def test_phases():
    common = dict(
        pool="p",
        placed_reason="PoolSelected",
        placed_message="m",
        pool_available=True,
        pool_message="ok",
        generation=1,
        now=NOW,
    )
    assert status.placed_status({}, deployment=dep(1, 1), url="http://x", **common)["phase"] == "Ready"
    assert status.placed_status({}, deployment=dep(1, 0), url="http://x", **common)["phase"] == "Deploying"
    assert status.placed_status({}, deployment=dep(0, 0), url="http://x", **common)["phase"] == "Pending"
    pending = status.pending_status({}, "NoEligiblePool", "none", 1, NOW)
    assert pending["phase"] == "Pending" and pending["url"] is None
    invalid = status.invalid_status({}, ["spec.image is required"], 1, NOW)
    assert invalid["phase"] == "Failed"
    assert {c["type"]: c["reason"] for c in invalid["conditions"]} == {"Placed": "InvalidSpec", "Ready": "InvalidSpec"}


def test_pool_unhealthy_since_reads_the_condition():
    conds = status.set_condition([], status.POOL_AVAILABLE, False, "NoReadyNodes", "x", NOW)
    assert status.pool_unhealthy_since({"conditions": conds}) == NOW
    assert status.pool_unhealthy_since({}) is None
