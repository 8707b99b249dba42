"""Links that fail: one robot streaming at 25 FPS with a 200 ms deadline to netapps behind emulated 5G links that
lose packets, go down, or slow down mid-run, for each client policy, side by side in one run.

    python -m bench.resilience                                  # 60 s a run, the three scenarios, five policies
    python -m bench.resilience --duration 30 --scenarios outage --policies single,fallback

Two netapps run as their own processes: the "edge" one behind the scenario's link, and the "cloud" one behind an
independent 5G link with 15 ms more delay each way (another site, another carrier). The robot (bench/robot.py, its
own process) sends pre-encoded 640x480 JPEG frames of the shared video. Policies:

* single: the edge netapp alone (what a robot does today);
* primary: edge, failing over to cloud on errors or missed deadlines, and back;
* hedge: every frame to both, the first result wins;
* adaptive: edge alone while it meets its deadlines, both from its first miss until it recovers;
* fallback: the edge netapp, and YOLOX-Nano on the robot's CPU (one thread) while the edge misses its deadlines.

Writes results/resilience-<time>/table.md, runs.json and one latency-over-time plot per scenario (outages shaded).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from bench.linkemu import PROFILES, Change, LinkEmulator, LinkProfile, LinkSchedule, Outages
from bench.netapps import netapp_process, start_run
from netapp.client.stats import percentile

ROOT = Path(__file__).resolve().parent.parent

FIVE_G = PROFILES["5g"]
CLOUD = dataclasses.replace(FIVE_G, name="5g-cloud", delay_ms=FIVE_G.delay_ms + 15)
POLICIES = {
    "single": ["--policy", "primary"],
    "primary": ["--policy", "primary"],
    "hedge": ["--policy", "hedge"],
    "adaptive": ["--policy", "adaptive"],
    "fallback": ["--policy", "primary"],
}
SCENARIOS = ("loss", "outage", "rising")


@dataclasses.dataclass(frozen=True)
class Scenario:
    name: str
    what: str
    edge: LinkProfile
    edge_schedule: LinkSchedule
    cloud: LinkProfile
    event_s: float | None  # when the edge link goes bad (first outage, delay change), for recovery times


def scenario(name: str, duration_s: float) -> Scenario:
    if name == "loss":
        lossy, cloud = dataclasses.replace(FIVE_G, loss_pct=1.0), dataclasses.replace(CLOUD, loss_pct=1.0)
        return Scenario(name, "5G, 1 % loss both links", lossy, LinkSchedule(), cloud, None)
    if name == "outage":
        return Scenario(name, "5G, edge down 3 s every 20 s", FIVE_G, LinkSchedule(outages=Outages(3, 20)), CLOUD, 20.0)
    if name == "rising":
        at = duration_s / 2
        change = LinkSchedule(changes=(Change(at, delay_ms=150),))
        return Scenario(name, f"5G, edge delay 10 -> 150 ms at {at:g} s", FIVE_G, change, CLOUD, at)
    raise SystemExit(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")


@contextlib.contextmanager
def links(sc: Scenario, edge_port: int, cloud_port: int) -> Iterator[tuple[LinkEmulator, str, str]]:
    """Fresh links for one run; the edge link's schedule is held until the robot streams (`run_robot`)."""
    edge = LinkEmulator(sc.edge, ("127.0.0.1", edge_port), schedule=sc.edge_schedule, hold_schedule=True)
    cloud = LinkEmulator(sc.cloud, ("127.0.0.1", cloud_port))
    with edge as (eh, ep), cloud as (ch, cp):
        yield edge, f"http://{eh}:{ep}", f"http://{ch}:{cp}"


def run_robot(args, policy: str, edge: LinkEmulator, edge_url: str, cloud_url: str) -> dict:
    urls = ["--url", edge_url] + ([] if policy in ("single", "fallback") else ["--url", cloud_url])
    cmd = [
        sys.executable,
        "-m",
        "bench.robot",
        "--transport",
        args.transport,
        "--video",
        args.video,
        "--fps",
        str(args.fps),
        "--duration",
        str(args.duration),
        "--deadline-ms",
        str(args.deadline_ms),
        "--pre-encode",
        *urls,
        *POLICIES[policy],
    ]
    if policy == "fallback":
        cmd += ["--fallback-model", args.model]
    robot = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert robot.stdout is not None
        first = robot.stdout.readline()  # once it streams: the link's schedule starts then, on the robot's clock
        if first:
            edge.start_schedule(json.loads(first)["streaming_at"])
        out, _ = robot.communicate(timeout=args.duration + 180)
    finally:
        if robot.poll() is None:
            robot.kill()
            robot.wait()
    if robot.returncode != 0:
        raise RuntimeError(f"robot ({policy}) failed with code {robot.returncode}")
    return json.loads(out.strip().splitlines()[-1])


def measure(
    summary: dict, deadline_ms: float, duration_s: float, event_s: float | None, outages: list[tuple[float, float]]
) -> dict:
    """The figures a robot cares about, from one run's per-result records."""
    records = summary["records"]  # (arrival s, latency ms, source, late)
    on_time = sorted(t for t, _, _, late in records if not late)
    per_s = [0] * max(1, math.floor(duration_s))
    for t in on_time:
        if t < len(per_s):
            per_s[int(t)] += 1
    # The longest span with no result within its deadline, from the stream's start to its end.
    edges = [0.0, *(t for t in on_time if t <= duration_s), duration_s]
    gaps = list(zip(edges, edges[1:], strict=False))
    gap_s, gap_at = max((b - a, a) for a, b in gaps)
    # The same over the outages only: what the link's failure costs, apart from a busy machine's slow spells.
    outage_gap_s = max((b - a for a, b in gaps if any(a < end and b > start for start, end in outages)), default=0)
    latencies = [lat for _, lat, _, _ in records]
    recovery = None
    if event_s is not None:
        after = [t for t in on_time if t > event_s + 0.05]
        recovery = round(after[0] - event_s, 2) if after else None
    return {
        "within_per_s": round(sum(per_s) / len(per_s), 2),
        "min_within_per_s": min(per_s),
        "longest_gap_ms": round(gap_s * 1000),
        "longest_gap_at_s": round(gap_at, 2),
        "outage_gap_ms": round(outage_gap_s * 1000) if outages else None,
        "p50": round(percentile(latencies, 50), 1) if latencies else None,
        "p95": round(percentile(latencies, 95), 1) if latencies else None,
        "p99": round(percentile(latencies, 99), 1) if latencies else None,
        "offered": summary["frames_offered"],
        "results": summary["results"],
        "late": summary["late"],
        "no_result": summary["frames_offered"] - summary["results"],
        "deadline_dropped": summary["deadline_dropped"],
        "discarded": summary["discarded"],
        "switches": summary["switches"],
        "by_source": summary["by_source"],
        "first_on_time_after_event_s": recovery,
    }


def table(rows: list[dict], deadline_ms: float) -> str:
    out = [
        f"| scenario | policy | within {deadline_ms:g} ms /s (min) | longest gap ms (over outages) "
        "| p50 / p95 / p99 ms | no result "
        "| late | dropped by netapp (deadline) | hedged discarded | switches | by source |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        sources = ", ".join(f"{k} {v}" for k, v in sorted(r["by_source"].items()))
        out.append(
            f"| {r['scenario']} | {r['policy']} | {r['within_per_s']} ({r['min_within_per_s']}) "
            f"| {r['longest_gap_ms']} at {r['longest_gap_at_s']:g} s"
            + (f" ({r['outage_gap_ms']})" if r["outage_gap_ms"] is not None else "")
            + " "
            f"| {r['p50']} / {r['p95']} / {r['p99']} | {r['no_result']} | {r['late']} | {r['deadline_dropped']} "
            f"| {r['discarded']} | {r['switches']} | {sources} |"
        )
    return "\n".join(out)


def goals(rows: list[dict], deadline_ms: float) -> str:
    by = {(r["scenario"], r["policy"]): r for r in rows}
    lines = []
    single, hedge = by.get(("loss", "single")), by.get(("loss", "hedge"))
    if single and hedge and single["p99"] and hedge["p99"]:
        ratio = hedge["p99"] / single["p99"]
        lines.append(
            f"* (a) loss: hedge p99 {hedge['p99']} ms vs single {single['p99']} ms = {ratio:.2f}x "
            f"(goal: at most 0.5x): {'met' if ratio <= 0.5 else 'not met'}"
        )
    for policy in ("fallback", "single"):
        r = by.get(("outage", policy))
        if r:
            ok = r["outage_gap_ms"] <= deadline_ms
            lines.append(
                f"* (b) outage, {policy}: the longest span without a result within the deadline over an outage is "
                f"{r['outage_gap_ms']} ms, {r['longest_gap_ms']} ms over the whole run "
                f"(goal with the fallback: at most {deadline_ms:g} ms): {'met' if ok else 'not met'}"
            )
    for policy in ("primary", "adaptive"):
        r = by.get(("rising", policy))
        if r and r["first_on_time_after_event_s"] is not None:
            lines.append(
                f"* (c) rising delay, {policy}: first result within the deadline {r['first_on_time_after_event_s']} s "
                "after the change (the client's own switch; the middleware's switchover is not built)"
            )
    return "\n".join(lines)


def plot(rows: list[dict], runs: dict, out_dir: Path, deadline_ms: float) -> list[Path]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    written = []
    for name in dict.fromkeys(r["scenario"] for r in rows):
        policies = [r for r in rows if r["scenario"] == name]
        fig, axes = plt.subplots(len(policies), 1, figsize=(10, 1.9 * len(policies)), sharex=True, squeeze=False)
        for ax, row in zip(axes[:, 0], policies, strict=True):
            run = runs[(name, row["policy"])]
            for start, end in run["outages"]:
                ax.axvspan(start, end, color="tab:red", alpha=0.15, lw=0)
            if run["event_s"] is not None and not run["outages"]:
                ax.axvline(run["event_s"], color="tab:red", ls="--", lw=1)
            for source in sorted({s for _, _, s, _ in run["records"]}):
                pts = [(t, lat) for t, lat, s, _ in run["records"] if s == source]
                ax.scatter([p[0] for p in pts], [p[1] for p in pts], s=3, label=source)
            ax.axhline(deadline_ms, color="grey", ls=":", lw=1)
            ax.set_yscale("log")
            ax.set_ylabel(f"{row['policy']}\nms", fontsize=8)
            ax.legend(fontsize=6, loc="upper right", markerscale=3)
        axes[-1, 0].set_xlabel("seconds (red: edge link down, or its delay change)")
        fig.suptitle(f"Latency of each result over time: {name}", fontsize=10)
        fig.tight_layout()
        path = out_dir / f"resilience-{name}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def main() -> int:
    shared = ROOT.parent / "shared"
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=str(shared / "models" / "yolox_nano.onnx"))
    p.add_argument("--video", default=str(shared / "media" / "pedestrians.avi"))
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--duration", type=float, default=60.0, help="seconds per run")
    p.add_argument("--deadline-ms", type=float, default=200.0)
    p.add_argument("--transport", default="ws", choices=("ws", "http"))
    p.add_argument("--scenarios", default=",".join(SCENARIOS))
    p.add_argument("--policies", default=",".join(POLICIES))
    p.add_argument("--serve-args", default="--threads 1", help="for each `netapp serve` (two share this machine)")
    p.add_argument("--out", default=str(ROOT / "results"))
    args = p.parse_args()
    out_dir = start_run("resilience", args.out, (args.model, args.video))
    if out_dir is None:
        return 2
    rows, runs = [], {}
    serve_args = args.serve_args.split()
    with (
        netapp_process(args.model, serve_args) as (_, edge_port),
        netapp_process(args.model, serve_args) as (
            _,
            cloud_port,
        ),
    ):
        for name in args.scenarios.split(","):
            sc = scenario(name, args.duration)
            for policy in args.policies.split(","):
                if policy not in POLICIES:
                    raise SystemExit(f"unknown policy {policy!r}; known: {', '.join(POLICIES)}")
                with links(sc, edge_port, cloud_port) as (edge, edge_url, cloud_url):
                    summary = run_robot(args, policy, edge, edge_url, cloud_url)
                    offset = summary["start_monotonic"] - edge.started_at  # link clock -> robot clock
                names = {edge_url: "edge", cloud_url: "cloud"}  # sources by role, not by URL
                summary["records"] = [(t, lat, names.get(src, src), late) for t, lat, src, late in summary["records"]]
                summary["by_source"] = {names.get(k, k): v for k, v in summary["by_source"].items()}
                event = None if sc.event_s is None else sc.event_s - offset
                outages = [(a - offset, b - offset) for a, b in sc.edge_schedule.outage_windows(args.duration + offset)]
                measured = measure(summary, args.deadline_ms, args.duration, event, outages)
                row = {"scenario": name, "policy": policy} | measured
                rows.append(row)
                runs[(name, policy)] = {"records": summary["records"], "outages": outages, "event_s": event}
                print(
                    f"{name:7} {policy:9} {row['within_per_s']:5.1f} within/s (min {row['min_within_per_s']}), "
                    f"gap {row['longest_gap_ms']} ms, p99 {row['p99']} ms",
                    file=sys.stderr,
                    flush=True,
                )
    scenarios = "; ".join(f"{n}: {scenario(n, args.duration).what}" for n in args.scenarios.split(","))
    report = (
        f"{args.fps:g} FPS, {args.duration:g} s a run, deadline {args.deadline_ms:g} ms, {args.transport}. "
        f"{scenarios}; cloud link: 5G + 15 ms each way.\n\n{table(rows, args.deadline_ms)}\n\n"
        f"{goals(rows, args.deadline_ms)}\n"
    )
    (out_dir / "table.md").write_text(report)
    raw = {f"{n}/{p}": run for (n, p), run in runs.items()}
    (out_dir / "runs.json").write_text(json.dumps({"rows": rows, "runs": raw}))
    written = plot(rows, runs, out_dir, args.deadline_ms)
    print(report)
    print(f"written: {out_dir}/table.md, runs.json" + "".join(f", {w.name}" for w in written))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
