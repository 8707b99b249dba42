"""An uplink that adapts: `netapp stream` (the shared 1280x720 video at 10 fps) against a real netapp through the
link emulator (the 5G profile's delay and jitter, the uplink capped or changing), each row with `--adapt auto` and
`--adapt off` side by side, in one run.

    python -m bench.uplink                              # every row (about 8 minutes)
    python -m bench.uplink --rows 1.5,4 --duration 15   # some rows
    python -m bench.uplink --quick --rows 4             # a few seconds a row (the smoke test)

Rows (`rows`): a steady 0.25, 0.5, 0.75, 1.5 and 4 Mbit/s uplink, and one unshaped (the 5G delay alone); a swing
4 -> 0.25 -> 4 Mbit/s (20 s each: `swing4`, issue 43); a step trace 15.6 -> 1.5 -> 15.6 Mbit/s (20 s each); a trace that
swings tenfold (`swing_trace`, synthetic: bench/README.md names its model); an unconstrained uplink at an accuracy
floor of 0.95; 8 robots sharing one 10 Mbit/s uplink. Columns: results/s, latency p50 and p95, the share of results
within the budget, KB per frame, and F1 against the same frames detected at full quality (the source's frames,
uncompressed, in this process: what a loopback run at full quality answers), boxes matched by
`netapp.models.matching` (IoU >= 0.5, same class), persons per result, the codecs the frames went in, and for
a trace, the last result over the budget after each step. Modes (`--modes`): `auto` (the adapter, JPEG or H.264
as the uplink allows), `jpeg` (the adapter in JPEG alone: `--adapt auto-one-codec`, before issue 43), `off`, `full`.
Writes results/uplink-<time>/table.md, runs.json, uplink.png (latency and the chosen KB per frame over time) and
by-uplink.png (results/s and F1 against the uplink's rate, a line per mode); `--plot PATH` writes the first there
too, `--plot-by-uplink PATH` the second.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench.linkemu import PROFILES, Change, LinkEmulator, LinkSchedule
from bench.netapps import netapp_process, start_run
from bench.robots import estimated_capacity
from netapp.client.stats import percentile
from netapp.models.matching import agreement_f1

ROOT = Path(__file__).resolve().parent.parent
FIVE_G = PROFILES["5g"]
MODES = {  # how a robot sends: the uplink adapts; it does not (frames fitted to the model); nor that (before issue 21)
    "auto": ["--adapt", "auto"],
    "jpeg": ["--adapt", "auto-one-codec"],  # the adapter before issue 43: JPEG alone
    "off": ["--adapt", "off"],
    "full": ["--adapt", "off", "--full-frames"],
}
STEP_S = 20.0  # each level of the step trace
SWING_EVERY_S = 2.0  # a new rate this often in the swing trace
SWING_RANGE_MBIT = (0.5, 5.0)  # log-uniform over a tenfold range: a cell's edge (issue 21: 1 to 5, tenfold swings)
WINDOW_S = 1.0  # the rolling window of the p95 after a step


@dataclasses.dataclass(frozen=True)
class Row:
    name: str
    what: str
    up_mbit: float | None  # None: unshaped
    changes: tuple[Change, ...] = ()
    duration_s: float | None = None  # None: --duration
    robots: int = 1
    floor: float | None = None  # None: the client's default
    steps: tuple[float, ...] = ()  # when the rate steps (for the recovery column)


def swing_trace(duration_s: float, seed: int = 21) -> tuple[Change, ...]:
    """A synthetic uplink that swings tenfold within seconds: every `SWING_EVERY_S` a rate drawn log-uniformly from
    `SWING_RANGE_MBIT` (seeded, so every run sees the same trace)."""
    rng = random.Random(seed)
    low, high = SWING_RANGE_MBIT
    changes, t = [], 0.0
    while t < duration_s:
        rate = round(low * (high / low) ** rng.random(), 2)
        changes.append(Change(t, up_mbit=rate))
        t += SWING_EVERY_S
    return tuple(changes)


def rows(duration_s: float, quick: bool) -> dict[str, Row]:
    step = 3.0 if quick else STEP_S
    long = 3 * step
    return {
        "0.25": Row("0.25", "uplink 0.25 Mbit/s", 0.25),
        "0.5": Row("0.5", "uplink 0.5 Mbit/s", 0.5),
        "0.75": Row("0.75", "uplink 0.75 Mbit/s", 0.75),
        "1.5": Row("1.5", "uplink 1.5 Mbit/s", 1.5),
        "4": Row("4", "uplink 4 Mbit/s", 4.0),
        "step": Row(
            "step",
            f"15.6 -> 1.5 -> 15.6 Mbit/s, {step:g} s each",
            15.6,
            (Change(step, up_mbit=1.5), Change(2 * step, up_mbit=15.6)),
            long,
            steps=(step, 2 * step),
        ),
        "swing4": Row(
            "swing4",
            f"4 -> 0.25 -> 4 Mbit/s, {step:g} s each",
            4.0,
            (Change(step, up_mbit=0.25), Change(2 * step, up_mbit=4.0)),
            long,
            steps=(step, 2 * step),
        ),
        "unshaped": Row("unshaped", "unshaped uplink (5G delay)", None),
        "swing": Row("swing", "tenfold swings (synthetic)", None, swing_trace(long), long),
        "unconstrained": Row("unconstrained", "unshaped uplink, accuracy floor 0.95", None, floor=0.95),
        "fleet8": Row("fleet8", "8 robots, one 10 Mbit/s uplink", 10.0, robots=8),
    }


def thin_uplink(port: int, up_mbit: float | None, link_mode: str, changes: tuple[Change, ...] = ()) -> LinkEmulator:
    """The link to a netapp on `port` on loopback: the 5G profile's delay and jitter without loss (so rows differ by
    rate alone), the uplink capped at `up_mbit` (None: unshaped), `changes` from `start_schedule()` on."""
    profile = dataclasses.replace(FIVE_G, loss_pct=0.0, rate_mbit_up=up_mbit)
    schedule = LinkSchedule(changes=changes)
    return LinkEmulator(profile, ("127.0.0.1", port), mode=link_mode, seed=1, schedule=schedule, hold_schedule=True)


# -- one run -----------------------------------------------------------------------------------------------------


def robot_command(args: argparse.Namespace, url: str, mode: str, row: Row, duration_s: float, jsonl: Path) -> list:
    cmd = [sys.executable, "-m", "netapp", "stream", url, "--source", args.video, "--fps", str(args.fps)]
    cmd += ["--duration", str(duration_s), "--json", "--jsonl", str(jsonl), *MODES[mode]]
    cmd += ["--budget-ms", str(args.budget_ms)]
    if row.floor is not None:
        cmd += ["--accuracy-floor", str(row.floor)]
    return cmd


def first_line_within(paths: list[Path], procs: list[subprocess.Popen], timeout_s: float) -> bool:
    """Whether every robot wrote its first result before `timeout_s` (polled: the robots are other processes)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if all(p.is_file() and p.stat().st_size > 0 for p in paths):
            return True
        if any(proc.poll() is not None for proc in procs):
            return False
        time.sleep(0.05)  # polling another process's file, not synchronisation within this one
    return False


def run(args: argparse.Namespace, port: int, row: Row, mode: str, out_dir: Path) -> dict[str, Any]:
    """One row in one mode: the robots' summaries and per-result records, on the link's clock."""
    duration = row.duration_s or args.duration
    emu = thin_uplink(port, row.up_mbit, args.link_mode, row.changes)
    with emu as (host, link_port):
        url = f"http://{host}:{link_port}"
        jsonls = [out_dir / f"{row.name}-{mode}-{i}.jsonl" for i in range(row.robots)]
        procs = []
        for jsonl in jsonls:
            jsonl.unlink(missing_ok=True)
            cmd = robot_command(args, url, mode, row, duration, jsonl)
            procs.append(
                subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
            )
        capacity = None
        try:
            first_line_within(jsonls, procs, 60)
            started_wall = time.time()
            emu.start_schedule()
            if row.robots > 1:  # the netapp's own estimate while they stream
                time.sleep(min(duration / 2, 10))
                capacity = estimated_capacity([f"http://127.0.0.1:{port}"])
            outs = [proc.communicate(timeout=duration + 120)[0] for proc in procs]
        finally:
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
    summaries = []
    for proc, out, jsonl in zip(procs, outs, jsonls, strict=True):
        if proc.returncode not in (0, 1):
            raise RuntimeError(f"robot ({row.name}, {mode}) failed with code {proc.returncode}")
        summaries.append(json.loads(out.strip().splitlines()[-1]))
        jsonl.with_suffix(".summary.json").write_text(json.dumps(summaries[-1]))  # kept beside its results
    records = [[record(line, started_wall) for line in j.read_text().splitlines() if line.strip()] for j in jsonls]
    capacity = None if capacity is None else round(capacity, 1)
    return {"summaries": summaries, "records": records, "duration_s": duration, "capacity": capacity}


def record(line: str, started_wall: float) -> dict[str, Any]:
    """A result line of a robot's jsonl, with its arrival on the link's clock (s since the schedule started)."""
    data = json.loads(line)
    sent = data.get("sent") or {}
    return {  # `timestamp`: when its frame was sent, on the robot's wall clock (ns)
        "t": (data["timestamp"] / 1e9 + data["latency_ms"] / 1000) - started_wall,
        "latency_ms": data["latency_ms"],
        "frame": data.get("frame"),
        "bytes": sent.get("bytes"),
        "codec": sent.get("codec"),
        "detections": data["detections"],
    }


# -- figures -------------------------------------------------------------------------------------------------------


def reference_detections(args: argparse.Namespace, frames: int) -> list[list[dict]]:
    """The source's first `frames` frames (as `netapp stream` reads them at --fps) detected at full quality."""
    from netapp.client.sources import open_source
    from netapp.models import Detector, DetectorConfig

    detector = Detector(DetectorConfig(args.model))
    detector.load()
    found = []
    for i, frame in enumerate(open_source(args.video, args.fps)):
        if i >= frames:
            break
        found.append(detector.detect(frame))
    return found


def recovery_s(records: list[dict], steps: tuple[float, ...], end_s: float, budget_ms: float) -> list[float | None]:
    """For each step: how long until the p95 of every `WINDOW_S` window that follows (up to the next step) is within
    the budget, windows starting every quarter of it; 0 when none is over (None: no results to tell)."""
    out: list[float | None] = []
    bounds = [*steps, end_s]
    for start, end in zip(bounds, bounds[1:], strict=False):
        times = sorted((r["t"], r["latency_ms"]) for r in records if start <= r["t"] < end)
        if not times:
            out.append(None)
            continue
        last_over = start
        t = start
        while t < end:
            window = [lat for at, lat in times if t <= at < t + WINDOW_S]
            if window and percentile(window, 95) > budget_ms:
                last_over = min(end, t + WINDOW_S / 4)
            t += WINDOW_S / 4
        out.append(round(last_over - start, 2))
    return out


def late_s(records: list[dict], steps: tuple[float, ...], end_s: float, budget_ms: float) -> list[float]:
    """For each step: how long after it the last result over the budget came, up to the next step (0: none)."""
    bounds = [*steps, end_s]
    out = []
    for start, end in zip(bounds, bounds[1:], strict=False):
        late = [r["t"] - start for r in records if start <= r["t"] < end and r["latency_ms"] > budget_ms]
        out.append(round(max(late, default=0.0), 2))
    return out


def persons(detections: list[dict]) -> int:
    return sum(d.get("class_name") == "person" for d in detections)


def codec_shares(records: list[dict]) -> dict[str, float] | None:
    """The share of results whose frame went in each codec (None: not adapted, the transport's own)."""
    codecs = [r["codec"] for r in records if r.get("codec")]
    return {c: round(codecs.count(c) / len(codecs), 3) for c in sorted(set(codecs))} if codecs else None


def figures(row: Row, mode: str, result: dict[str, Any], reference: list[list[dict]], budget_ms: float) -> dict:
    duration = result["duration_s"]
    records = [r for robot in result["records"] for r in robot]
    latencies = [r["latency_ms"] for r in records]
    per_robot = [len(robot) / duration for robot in result["records"]]
    pairs = [
        (reference[r["frame"]], r["detections"])
        for r in records
        if r["frame"] is not None and r["frame"] < len(reference)
    ]
    summaries = result["summaries"]
    sent = sum(s["frames_sent"] for s in summaries)
    byte_total = sum(s["bytes_per_frame"] * s["frames_sent"] for s in summaries)
    adapt = summaries[0].get("adapt") or {}
    return {
        "row": row.name,
        "what": row.what,
        "mode": mode,
        "results_per_s": round(sum(per_robot), 2),
        "p50": round(percentile(latencies, 50), 1) if latencies else None,
        "p95": round(percentile(latencies, 95), 1) if latencies else None,
        "within_budget": round(sum(lat <= budget_ms for lat in latencies) / len(latencies), 3) if latencies else None,
        "kb_per_frame": round(byte_total / sent / 1000, 1) if sent else None,
        "f1": round(agreement_f1([p[0] for p in pairs], [p[1] for p in pairs]), 3) if pairs else None,
        "fairness": round(min(per_robot) / max(per_robot), 2) if row.robots > 1 and max(per_robot) > 0 else None,
        "capacity": result["capacity"],
        "recovery_s": recovery_s(records, row.steps, duration, budget_ms) if row.steps else None,
        "late_s": late_s(records, row.steps, duration, budget_ms) if row.steps else None,
        "persons": round(sum(persons(r["detections"]) for r in records) / len(records), 2) if records else None,
        "codecs": codec_shares(records),
        "up_mbit": row.up_mbit if not row.changes else None,
        "settings": adapt.get("settings"),
        "changes": adapt.get("change_count"),
    }


def table(figs: list[dict], budget_ms: float) -> str:
    out = [
        f"| row | adapt | results/s | p50 ms | p95 ms | within {budget_ms:g} ms | KB per frame | F1 | persons | codec "
        "| more |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for f in figs:
        more = []
        if f["recovery_s"] is not None:
            more.append("p95 back within budget after each step: " + ", ".join(f"{s} s" for s in f["recovery_s"]))
            more.append("last result over budget after each step: " + ", ".join(f"{s} s" for s in f["late_s"]))
        if f["fairness"] is not None:
            more.append(f"fair share {f['fairness']}, netapp capacity {f['capacity'] or '-'} results/s")
        if f["settings"]:
            s = f["settings"]
            how = f"{s['bitrate_kbps']} kbit/s" if s.get("codec") == "h264" else f"q{s['jpeg_quality']}"
            more.append(f"last: {s.get('codec') or ''} long side {s['long_side'] or 'full'}, {how}, {s['fps']:g} fps")
        share = f"{100 * f['within_budget']:.0f} %" if f["within_budget"] is not None else "-"
        codecs = ", ".join(f"{c} {100 * s:.0f} %" for c, s in (f["codecs"] or {}).items()) or "jpeg"
        out.append(
            f"| {f['what']} | {f['mode']} | {f['results_per_s']} | {f['p50']} | {f['p95']} | {share} "
            f"| {f['kb_per_frame']} | {f['f1']} | {f['persons']} | {codecs} | {'; '.join(more)} |"
        )
    return "\n".join(out)


def plot(runs: dict[tuple[str, str], dict], chosen: list[str], path: Path, budget_ms: float) -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    names = [n for n in chosen if any((n, m) in runs for m in MODES)]
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 2.3 * len(names)), squeeze=False)
    for ax, name in zip(axes[:, 0], names, strict=True):
        kb = ax.twinx()
        for mode, colour in (("full", "tab:grey"), ("off", "tab:red"), ("jpeg", "tab:orange"), ("auto", "tab:blue")):
            result = runs.get((name, mode))
            if result is None:
                continue
            records = result["records"][0]
            ax.scatter([r["t"] for r in records], [r["latency_ms"] for r in records], s=3, color=colour, label=mode)
            sized = [(r["t"], r["bytes"] / 1000) for r in records if r["bytes"]]
            if sized:
                kb.plot(
                    [t for t, _ in sized], [b for _, b in sized], color="tab:green", lw=1, label="KB per frame (auto)"
                )
        ax.axhline(budget_ms, color="grey", ls=":", lw=1)
        ax.set_yscale("log")
        ax.set_ylabel(f"{name}\nlatency ms", fontsize=8)
        kb.set_ylabel("KB per frame", fontsize=8, color="tab:green")
        ax.legend(fontsize=6, loc="upper left", markerscale=3)
    axes[-1, 0].set_xlabel(
        "seconds (one robot; blue: --adapt auto, orange: JPEG alone, red: off, grey: off full frames; green: KB sent)"
    )
    fig.suptitle("Latency of each result and the chosen frame size over time", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


UNSHAPED_AT_MBIT = 10.0  # where the plot puts the unshaped uplink (beyond every capped row)


def plot_by_uplink(figs: list[dict], path: Path) -> bool:
    """Results/s and F1 against the uplink's rate (the steady rows; the unshaped one at `UNSHAPED_AT_MBIT`), a line
    per mode, each point marked with the codec most of its frames went in."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    steady = [f for f in figs if f["row"] in ("0.25", "0.5", "0.75", "1.5", "4", "unshaped")]
    if not steady:
        return False
    fig, (rate_ax, f1_ax) = plt.subplots(1, 2, figsize=(10, 3.6))
    colours = {"auto": "tab:blue", "jpeg": "tab:orange", "off": "tab:red", "full": "tab:grey"}
    for mode, colour in colours.items():
        points = sorted((f["up_mbit"] or UNSHAPED_AT_MBIT, f) for f in steady if f["mode"] == mode)
        if not points:
            continue
        xs = [x for x, _ in points]
        label = {"auto": "auto (JPEG or H.264)", "jpeg": "auto, JPEG alone", "off": "off"}.get(mode, mode)
        rate_ax.plot(xs, [f["results_per_s"] for _, f in points], "-", color=colour, label=label)
        f1_ax.plot(xs, [f["f1"] or 0 for _, f in points], "-", color=colour, label=label)
        for x, f in points:
            shares = f["codecs"] or {"jpeg": 1.0}
            marker = "s" if max(shares, key=shares.get) == "h264" else "o"
            rate_ax.plot([x], [f["results_per_s"]], marker, color=colour)
            f1_ax.plot([x], [f["f1"] or 0], marker, color=colour)
    for ax, what in ((rate_ax, "results/s"), (f1_ax, "F1 against full quality")):
        ax.set_xscale("log")
        ax.set_xlabel("uplink Mbit/s (right: unshaped); square: mostly H.264, circle: JPEG", fontsize=8)
        ax.set_ylabel(what)
        ax.legend(fontsize=7)
    fig.suptitle("A robot's results through a thin uplink (720p at 10 fps, 5G delay, YOLOX-Nano)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def main() -> int:
    shared = ROOT.parent / "shared"
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=str(shared / "models" / "yolox_nano.onnx"))
    p.add_argument("--video", default=str(shared / "media" / "pedestrians.avi"))
    p.add_argument("--fps", type=float, default=10.0)
    p.add_argument("--duration", type=float, default=20.0, help="seconds of a steady row (the traces: 3 steps)")
    p.add_argument("--budget-ms", type=float, default=150.0)
    p.add_argument("--rows", default="0.75,1.5,4,step,swing,unconstrained,fleet8")
    p.add_argument(
        "--modes",
        default="auto,off",
        help="of auto, jpeg (the adapter in JPEG alone: before issue 43), off, full (off, --full-frames: before 21)",
    )
    p.add_argument("--link-mode", default="auto", choices=("auto", "netns", "userspace"))
    p.add_argument("--quick", action="store_true", help="a few seconds a row (a smoke test, not a measurement)")
    p.add_argument("--serve-args", default="", help="for `netapp serve`")
    p.add_argument("--plot", help="also write the plot here (e.g. docs/uplink.png)")
    p.add_argument("--plot-by-uplink", help="also write results/s and F1 against the uplink here")
    p.add_argument("--out", default=str(ROOT / "results"))
    args = p.parse_args()
    if args.quick:
        args.duration = min(args.duration, 4.0)
    out_dir = start_run("uplink", args.out, (args.model, args.video))
    if out_dir is None:
        return 2
    known = rows(args.duration, args.quick)
    chosen = [n for n in args.rows.split(",") if n]
    unknown = [n for n in chosen if n not in known]
    if unknown:
        raise SystemExit(f"unknown rows {unknown}; known: {', '.join(known)}")
    modes = [m for m in args.modes.split(",") if m]
    if not set(modes) <= set(MODES):
        raise SystemExit(f"unknown modes {modes}; known: {', '.join(MODES)}")
    longest = max(known[n].duration_s or args.duration for n in chosen)
    reference = reference_detections(args, int(longest * args.fps) + 20)  # a robot sends no more frames than these
    runs: dict[tuple[str, str], dict] = {}
    with netapp_process(args.model, args.serve_args.split()) as (_, port):
        for name in chosen:
            for mode in modes:
                runs[(name, mode)] = run(args, port, known[name], mode, out_dir)
                print(f"{name} {mode}: done", file=sys.stderr, flush=True)
    figs = [figures(known[n], m, runs[(n, m)], reference, args.budget_ms) for n, m in runs]
    load = os.getloadavg()
    report = (
        f"{args.fps:g} fps of {Path(args.video).name} (1280x720), 5G delay and jitter (no loss), budget "
        f"{args.budget_ms:g} ms, link {args.link_mode}; load average {load[0]:.2f} {load[1]:.2f} at the end\n\n"
        f"{table(figs, args.budget_ms)}\n"
    )
    (out_dir / "table.md").write_text(report)
    (out_dir / "runs.json").write_text(json.dumps({"figures": figs}))
    written = [out_dir / "uplink.png", *([Path(args.plot)] if args.plot else [])]
    plotted = all(plot(runs, chosen, path, args.budget_ms) for path in written)
    by_uplink = [out_dir / "by-uplink.png", *([Path(args.plot_by_uplink)] if args.plot_by_uplink else [])]
    if all(plot_by_uplink(figs, path) for path in by_uplink):
        written += by_uplink
    print(report)
    print(f"written: {out_dir}/table.md, runs.json" + (", " + ", ".join(map(str, written)) if plotted else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
