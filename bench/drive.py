"""A robot driving through pools: how many of its results come back within its budget, and how many frames it loses.

    python -m bench.drive --model ../shared/models/yolox_nano.onnx --runs 3 [--modes route,reactive]

The middleware (local backend) runs in this process with 3 pools, each a netapp process on this machine reached
through an emulated link of its own (bench/linkemu/pools.py). The robot drives through the pools' cells one after
another, a leg of --leg seconds each: pool i is near (--near-ms one way) from a little before its leg to a little
after (--overlap s; cells overlap) and far (--far-ms, over the budget) otherwise, all on one clock. The robot
deploys on the first pool and streams 640x480 JPEG frames at 10 FPS over Socket.IO, reporting its p95 against its
budget (--budget-ms) every 0.5 s. Two modes, a column each:

- `route`: the robot tells the middleware its route as it starts (each next pool at the start of its leg); the
  middleware readies each pool ahead and moves the robot there half a second before its eta;
- `reactive`: no route; the catalogue keeps a warm standby on the robot's next-best pool and the middleware moves the
  robot when its latency breaches the budget (into a warm netapp at the first report over budget, cold after the
  sustain window).

Every move is hedged on the robot (`NetAppClient.move_to`). Counted over the frames sent during the drive: the share
of them whose result came back within the budget (a frame without a result counts as not), frames lost, results
over budget, and the moves the middleware made (why, and when against the leg's start).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

from netapp_middleware.switchover.ahead import AheadPolicy
from netapp_middleware.switchover.decision import SwitchPolicy

from bench.linkemu import Change, LinkProfile, LinkSchedule
from bench.linkemu.pools import PoolLinks
from bench.switchover import ROBOT, SECRET, Middleware, print_table, robot_args, robot_frame, trigger
from netapp.client.middleware import MiddlewareClient

POOLS = ("pool-a", "pool-b", "pool-c")
MODES = ("route", "reactive")


def drive_schedules(
    pools: Sequence[str], leg_s: float, overlap_s: float, near_ms: float, far_ms: float
) -> dict[str, tuple[LinkProfile, LinkSchedule]]:
    """Each pool's link over the drive (pure): pool i near from `i * leg_s - overlap_s` to `(i + 1) * leg_s +
    overlap_s` (the first from the start, the last to the end), far otherwise."""
    if not 0 <= overlap_s < leg_s / 2:
        raise ValueError("the cells' overlap must be under half a leg")
    links = {}
    for i, pool in enumerate(pools):
        near_from, near_to = i * leg_s - overlap_s, (i + 1) * leg_s + overlap_s
        changes = []
        if near_from > 0:
            changes.append(Change(near_from, delay_ms=near_ms))
        if i < len(pools) - 1:
            changes.append(Change(near_to, delay_ms=far_ms))
        base = LinkProfile(pool, near_ms if near_from <= 0 else far_ms, 0.0, 0.0, None, None, f"the link to {pool}")
        links[pool] = (base, LinkSchedule(changes=tuple(changes)))
    return links


def within_budget(latencies_ms: dict[int, float], sent: Sequence[int], budget_ms: float) -> tuple[int, int]:
    """(frames whose result came within the budget, frames without a result) of the frames `sent` (pure)."""
    within = sum(1 for ts in sent if latencies_ms.get(ts, float("inf")) <= budget_ms)
    return within, sum(1 for ts in sent if ts not in latencies_ms)


def one_drive(mw_url: str, links: PoolLinks, frame: bytes, args: argparse.Namespace, mode: str) -> dict[str, Any]:
    pools = list(POOLS)
    with MiddlewareClient(mw_url, ROBOT, SECRET) as mw:
        first = mw.deploy("object-detection", placement=pools[0], timeout=120)
        start_wall = time.time() + args.lead_in
        if mode == "route":  # each next pool at the start of its leg
            mw.route(first, [(pool, start_wall + i * args.leg) for i, pool in enumerate(pools) if i])
        deadline = time.monotonic() + 120
        while not all(s["phase"] == "Ready" for s in mw.standbys()["standbys"]) or not mw.standbys()["standbys"]:
            if time.monotonic() > deadline:
                raise RuntimeError("the warm netapps were not Ready within 120 s")
            time.sleep(0.1)
        latencies: dict[int, float] = {}
        sent: list[int] = []
        with mw.netapp_client(first, budget_ms=args.budget_ms, report_every_s=0.5, transport="ws") as client:
            client.on_result = lambda result: latencies.__setitem__(result.timestamp, result.latency_ms)
            time.sleep(max(0.0, start_wall - time.time()))
            started = links.start_schedules()
            lost_before = client.stats.lost
            period, next_at, end = 1.0 / args.fps, started, started + len(pools) * args.leg
            while time.monotonic() < end:
                sent.append(client.send(frame))
                next_at += period
                time.sleep(max(0.0, next_at - time.monotonic()))
            client.wait_idle(3.0)  # the last frames' results
            lost = client.stats.lost - lost_before
        history = mw.status(first)["history"]
    within, unanswered = within_budget(latencies, sent, args.budget_ms)
    moves = [
        f"{m['to']} at {m['at'] - start_wall - pools.index(m['to']) * args.leg:+.1f} s ({trigger(m['message'])})"
        for m in history
        if m["to"] in pools
    ]
    return {
        "sent": len(sent),
        "within_pct": 100.0 * within / max(1, len(sent)),
        "over": len(sent) - within - unanswered,
        "unanswered": unanswered,
        "lost": lost,
        "moves": moves,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    robot_args(parser, MODES)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--leg", type=float, default=12.0, help="seconds in each pool's cell (default 12)")
    parser.add_argument("--overlap", type=float, default=1.5, help="seconds the cells overlap (default 1.5)")
    parser.add_argument("--near-ms", type=float, default=10.0, help="one-way delay to the near pool (default 10)")
    parser.add_argument("--far-ms", type=float, default=150.0, help="one-way delay to a far pool (default 150)")
    parser.add_argument("--budget-ms", type=float, default=150.0, help="the robot's latency budget (default 150)")
    parser.add_argument("--lead-in", type=float, default=8.0, help="seconds from the route to the drive's start")
    args = parser.parse_args()
    asked = robot_frame(args, MODES)
    if asked is None:
        return 2
    frame, modes = asked
    schedules = drive_schedules(POOLS, args.leg, args.overlap, args.near_ms, args.far_ms)
    rows: dict[str, list[dict[str, Any]]] = {}
    for mode in modes:
        for run in range(args.runs):
            links = PoolLinks(schedules, seed=run)
            policy = SwitchPolicy(min_dwell_s=5.0)  # a leg is longer than the dwell, shorter than the default 20 s
            ahead = AheadPolicy(min_dwell_s=5.0, warm_lead_s=60.0, idle_grace_s=5.0)
            try:
                with Middleware(
                    args.model, policy, standby=mode == "reactive", placements=POOLS, url_for=links.url_for, ahead=ahead
                ) as middleware:
                    row = one_drive(middleware.url, links, frame, args, mode)
            finally:
                links.close()
            rows.setdefault(mode, []).append(row)
            print(
                f"{mode} run {run + 1}: {row['within_pct']:.1f} % of {row['sent']} frames within "
                f"{args.budget_ms:g} ms; over {row['over']}, unanswered {row['unanswered']}, lost {row['lost']}; "
                f"moves: {'; '.join(row['moves']) or 'none'}",
                flush=True,
            )
    print(
        f"\n{len(POOLS)} pools, legs of {args.leg:g} s (cells overlap {args.overlap:g} s), one way {args.near_ms:g} ms "
        f"near / {args.far_ms:g} ms far, budget {args.budget_ms:g} ms, {args.fps:g} FPS, {args.runs} runs per mode"
    )
    print("(median / worst of the runs)\n")
    print_table(
        "",
        rows,
        [
            ("within_pct", "results within budget (% of frames sent)", min, ".1f"),
            ("over", "results over budget", max, "g"),
            ("unanswered", "frames without a result", max, "g"),
            ("lost", "frames lost", max, "g"),
        ],
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
