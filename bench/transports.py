"""Transport benchmark: the same 640x480 frames through each transport (and link), side by side in one run.

    python -m bench.transports --model ../shared/models/yolox_nano.onnx            # loopback, 10 and 25 FPS, 20 s
    python -m bench.transports --fps 10,25,60 --duration 20 --transports direct,http,ws
    python -m bench.transports --links loopback,wifi,5g --transports direct,http,ws,h264 --duration 60
    python -m bench.transports --fps 25 --duration 6 --repeat 3 --transports direct,http,ws,h264,frames,frames-h264
    python -m bench.transports --fps 25 --duration 6 --repeat 4 --variants base=../wt-base,new=.   # before/after

Each robot is its own process (bench/robot.py) and the netapp is another, so CPU and memory are measured apart.
Writes a Markdown table, JSON and PNG plots under results/transports-<time>/ and prints the table.

The netapp's per-frame overhead is measured two ways: the raw difference of p50 latencies from `direct` (the
in-process detector), and the difference of p50(latency - model time), each frame's model time being the
processor's `process()` call (a netapp's server-side `inference_ms`). The model's own time swings by several ms
between seconds even on a quiet machine, so only the second says what the netapp adds. Both are medians over
`--repeat` interleaved runs; the netapp and every direct detector are warmed up before they are timed.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil

from bench.netapps import VARIANTS_HELP, netapp_process, parse_variants, start_run

ROOT = Path(__file__).resolve().parent.parent


class ProcessMonitor:
    """CPU % (of one core) and peak RSS of a running process (the netapp) over a window, sampled in a thread."""

    def __init__(self, pid: int, period_s: float = 0.25) -> None:
        self.process = psutil.Process(pid)
        self.period_s = period_s
        self.peak_rss = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(psutil.Error):
                self.peak_rss = max(self.peak_rss, self.process.memory_info().rss)
            self._stop.wait(self.period_s)

    def __enter__(self) -> ProcessMonitor:
        self._t0 = time.monotonic()
        self._cpu0 = sum(self.process.cpu_times()[:2])
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        with contextlib.suppress(psutil.Error):
            self.cpu_s = sum(self.process.cpu_times()[:2]) - self._cpu0
            self.peak_rss = max(self.peak_rss, self.process.memory_info().rss)
        self.wall_s = time.monotonic() - self._t0
        self._stop.set()
        self._thread.join()

    @property
    def cpu_percent(self) -> float:
        return 100 * self.cpu_s / self.wall_s if self.wall_s else 0.0


def run_robot(
    args,
    transport: str,
    fps: float,
    url: str | None,
    server_pid: int | None,
    code: str | None = None,
    duration=None,
    command: list[str] | None = None,
) -> dict:
    """One robot process's run, measured: `command` runs another robot that prints bench/robot.py's summary."""
    duration = duration or args.duration
    cmd = command or [
        sys.executable,
        "-m",
        "bench.robot",
        "--transport",
        transport,
        "--video",
        os.path.abspath(args.video),
        "--fps",
        str(fps),
        "--duration",
        str(duration),
        "--size",
        args.size,
    ]
    if command is None:
        cmd += (
            ["--model", os.path.abspath(args.model), "--model-threads", str(args.model_threads)]
            if transport == "direct"
            else ["--url", url]
        )
        cmd += ["--pre-encode"] if args.pre_encode else []
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    # `python -m bench.robot` from a variant's checkout runs its robot and its client code (paths made absolute).
    robot = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env, cwd=code or ROOT)
    with ProcessMonitor(server_pid or robot.pid) as server_mon:
        out, _ = robot.communicate(timeout=duration + 120)
    if robot.returncode != 0:
        raise RuntimeError(f"robot {transport} at {fps} fps failed with code {robot.returncode}")
    summary = json.loads(out.strip().splitlines()[-1])
    frames = max(1, summary["results"])
    timed = [(lat, model) for lat, model in summary.pop("timed_ms", []) if model is not None]
    return summary | {
        "model_ms": percentile_or_none([m for _, m in timed], 50),
        "outside_model_ms": percentile_or_none([lat - m for lat, m in timed], 50),
        "transport": transport,
        "fps": fps,
        "robot_cpu": 100 * summary["loop_cpu_s"] / summary["duration_s"],
        "robot_rss_mb": summary["peak_rss_mb"],
        "robot_cpu_ms_per_frame": 1000 * summary["loop_cpu_s"] / frames,
        "server_cpu": server_mon.cpu_percent if transport != "direct" else None,
        "server_rss_mb": server_mon.peak_rss / 2**20 if transport != "direct" else None,
    }


@contextlib.contextmanager
def link(name: str, port: int):
    """The URL a robot uses to reach the netapp over the named link profile."""
    if name == "loopback":
        yield f"http://127.0.0.1:{port}"
        return
    from bench.linkemu import emulated_link

    with emulated_link(name, target=("127.0.0.1", port)) as (host, link_port):
        yield f"http://{host}:{link_port}"


def percentile_or_none(values: list[float], q: float) -> float | None:
    return statistics.quantiles(values, n=100, method="inclusive")[q - 1] if len(values) > 1 else None


def add_model_threads(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--model-threads",
        type=int,
        default=0,
        help="onnxruntime's threads for direct and every netapp (0: every core; 1 on 2 cores leaves one to the "
        "data path, as a model on a GPU would)",
    )


def model_threads_serve_args(args) -> list[str]:
    """`netapp serve`'s arguments for `--model-threads` (none for 0, its default)."""
    return ["--threads", str(args.model_threads)] if args.model_threads else []


def merge_repeats(rows: list[dict]) -> list[dict]:
    """One row per (variant, link, transport, fps): the median of each figure over the repeated runs (and, for the
    time outside the model, the spread of the runs' p50s)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["variant"], r["link"], r["transport"], r["fps"]), []).append(r)

    def med(runs, get):
        values = [get(r) for r in runs if get(r) is not None]
        return statistics.median(values) if values else None

    merged = []
    for runs in groups.values():
        row = dict(runs[0])
        row["runs"] = len(runs)
        row["latency_ms"] = {k: med(runs, lambda r, k=k: r["latency_ms"][k]) for k in runs[0]["latency_ms"]}
        for key in (
            "results_per_s",
            "robot_cpu",
            "robot_rss_mb",
            "robot_cpu_ms_per_frame",
            "server_cpu",
            "server_rss_mb",
            "bytes_per_frame",
            "model_ms",
            "outside_model_ms",
        ):
            row[key] = med(runs, lambda r, key=key: r[key])
        outside = [r["outside_model_ms"] for r in runs if r["outside_model_ms"] is not None]
        row["outside_model_spread_ms"] = (min(outside), max(outside)) if outside else None
        row["latencies_ms"] = [v for r in runs for v in r["latencies_ms"]]
        merged.append(row)
    return merged


def fmt(value, digits=1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def signed(value) -> str:
    return "-" if value is None else f"{value:+.1f}"


def table(rows: list[dict]) -> str:
    variants = len({r["variant"] for r in rows}) > 1
    head = (
        ("| variant " if variants else "")
        + "| link | transport | input FPS | results/s | latency p50 ms | p95 ms | model p50 ms | outside model p50 ms "
        "| robot CPU % | robot RSS MB | robot CPU ms/frame | server CPU % | server RSS MB | bytes/frame |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        lat = r["latency_ms"]
        lines.append(
            (f"| {r['variant'] or '-'} " if variants else "")
            + f"| {r['link']} | {r['transport']} | {r['fps']:g} | {r['results_per_s']:.1f} | {fmt(lat['p50'])} | "
            f"{fmt(lat['p95'])} | {fmt(r['model_ms'])} | {fmt(r['outside_model_ms'])} | "
            f"{fmt(r['robot_cpu'], 0)} | {fmt(r['robot_rss_mb'], 0)} | "
            f"{fmt(r['robot_cpu_ms_per_frame'])} | {fmt(r['server_cpu'], 0)} | {fmt(r['server_rss_mb'], 0)} | "
            f"{round(r['bytes_per_frame']) if r['transport'] != 'direct' else '-'} |"
        )
    return "\n".join(lines)


def paper_table(rows: list[dict]) -> str:
    """The layout of the paper's tables: per input rate, a block of metrics per transport, a column per link."""
    links = list(dict.fromkeys(r["link"] for r in rows))
    metrics = [
        ("robot CPU %", lambda r: fmt(r["robot_cpu"], 0)),
        ("robot RAM MB", lambda r: fmt(r["robot_rss_mb"], 0)),
        ("latency median ms", lambda r: fmt(r["latency_ms"]["p50"])),
        ("results/s", lambda r: f"{r['results_per_s']:.1f}"),
    ]
    out = []
    for fps in sorted({r["fps"] for r in rows}):
        out.append(f"\n**{fps:g} FPS input**\n")
        out.append("| transport | metric | " + " | ".join(links) + " |")
        out.append("|---|---|" + "---|" * len(links))
        for key in dict.fromkeys((r["variant"], r["transport"]) for r in rows):
            by_link = {r["link"]: r for r in rows if r["fps"] == fps and (r["variant"], r["transport"]) == key}
            if not by_link:
                continue
            label = " ".join(k for k in key if k)
            for name, get in metrics:
                cells = [get(by_link[link]) if link in by_link else "-" for link in links]
                out.append(f"| {label} | {name} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def overhead_ms(row: dict, direct: dict) -> tuple[float | None, float | None]:
    """(raw, outside the model): p50 latency over direct's, and p50(latency - model time) over direct's."""
    raw = row["latency_ms"]["p50"] - direct["latency_ms"]["p50"]
    if row["outside_model_ms"] is None or direct["outside_model_ms"] is None:
        return raw, None
    return raw, row["outside_model_ms"] - direct["outside_model_ms"]


def findings(rows: list[dict]) -> str:
    """The goals of the netapp issue, as measured: overhead over direct, results per second vs input and max."""
    out = []
    direct = {r["fps"]: r for r in rows if r["transport"] == "direct"}
    for r in rows:
        d = direct.get(r["fps"])
        if r["transport"] == "direct" or d is None or r["link"] != "loopback":
            continue
        raw, outside = overhead_ms(r, d)
        spread = r["outside_model_spread_ms"]
        runs = (
            f" (runs {spread[0] - d['outside_model_ms']:+.1f} to {spread[1] - d['outside_model_ms']:+.1f})"
            if spread and outside is not None
            else ""
        )
        variant = f"{r['variant']}: " if len(direct) and len({x["variant"] for x in rows}) > 1 else ""
        out.append(
            f"- {variant}{r['transport']} @ {r['fps']:g} FPS: overhead outside the model {signed(outside)} ms{runs}, "
            f"raw p50 {raw:+.1f} ms over direct; results/s {r['results_per_s']:.2f} = "
            f"{100 * r['results_per_s'] / r['fps']:.1f}% of input, "
            f"{100 * r['results_per_s'] / d['results_per_s']:.1f}% of direct"
        )
    loopback = {(r["variant"], r["transport"], r["fps"]): r for r in rows if r["link"] == "loopback"}
    for r in rows:
        base = loopback.get((r["variant"], r["transport"], r["fps"]))
        if r["link"] != "loopback" and base and base["results_per_s"]:
            out.append(
                f"- {r['transport']} @ {r['fps']:g} FPS over {r['link']}: {r['results_per_s']:.2f} results/s = "
                f"{100 * r['results_per_s'] / base['results_per_s']:.1f}% of loopback; p50 "
                f"{fmt(r['latency_ms']['p50'])} ms vs {fmt(base['latency_ms']['p50'])} ms"
            )
    return "\n".join(out)


def plots(rows: list[dict], out_dir: Path) -> list[Path]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    written = []
    fig, ax = plt.subplots(figsize=(max(6, len(rows) * 0.7), 4.5))
    labels = [f"{r['variant']}\n{r['link']}\n{r['transport']}\n{r['fps']:g} fps" for r in rows]
    ax.boxplot([r["latencies_ms"] or [0] for r in rows], showfliers=False)
    ax.set_xticks(range(1, len(rows) + 1), labels, fontsize=7)
    ax.set_ylabel("latency, ms (send to result)")
    ax.set_title("Latency distribution per transport and link")
    fig.tight_layout()
    fig.savefig(out_dir / "latency.png", dpi=120)
    written.append(out_dir / "latency.png")
    fig, ax = plt.subplots(figsize=(6, 4))
    for key in sorted({(r["variant"], r["link"], r["transport"]) for r in rows}):
        pts = sorted((r["fps"], r["results_per_s"]) for r in rows if (r["variant"], r["link"], r["transport"]) == key)
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=f"{key[2]} ({key[1]}, {key[0]})")
    top = max(r["fps"] for r in rows)
    ax.plot([0, top], [0, top], ls=":", color="grey", label="input rate")
    ax.set_xlabel("input FPS")
    ax.set_ylabel("results per second")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_dir / "results_per_second.png", dpi=120)
    written.append(out_dir / "results_per_second.png")
    return written


def main() -> int:
    shared = ROOT.parent / "shared"
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=str(shared / "models" / "yolox_nano.onnx"))
    p.add_argument("--video", default=str(shared / "media" / "pedestrians.avi"))
    p.add_argument("--fps", default="10,25", help="input rates, comma-separated")
    p.add_argument("--duration", type=float, default=20.0, help="seconds per run")
    p.add_argument("--transports", default="direct,http,ws")
    p.add_argument("--links", default="loopback", help="loopback, wifi, 5g (emulated; see bench/README.md)")
    p.add_argument("--size", default="640x480")
    p.add_argument("--serve-args", default="", help="extra arguments for `netapp serve`, e.g. '--prepare-threads 2'")
    p.add_argument("--repeat", type=int, default=1, help="runs per configuration, interleaved; the table shows medians")
    add_model_threads(p)
    p.add_argument(
        "--pre-encode",
        action="store_true",
        default=True,
        help="JPEG-encode before the timed loop (default; H.264 always encodes live)",
    )
    p.add_argument("--live-encode", dest="pre_encode", action="store_false", help="encode JPEG in the robot loop")
    p.add_argument(
        "--warmup",
        type=float,
        default=8.0,
        help="seconds each netapp is streamed to (ws, 25 FPS) before it is timed; direct warms up by itself",
    )
    p.add_argument("--variants", default="", help=VARIANTS_HELP + "; direct is run once per repeat for all")
    p.add_argument("--out", default=str(ROOT / "results"))
    args = p.parse_args()
    out_dir = start_run("transports", args.out, (args.model, args.video))
    if out_dir is None:
        return 2
    try:
        variants, serve_args = parse_variants(args.variants, args.serve_args.split() + model_threads_serve_args(args))
    except ValueError as exc:
        print(exc)
        return 2
    transports = args.transports.split(",")
    rows = []
    with contextlib.ExitStack() as stack:
        servers = {
            name: stack.enter_context(netapp_process(args.model, serve_args[name], code=code or None))
            for name, code in variants.items()
        }
        for name, (server, port) in servers.items():
            if args.warmup > 0 and set(transports) - {"direct"}:  # the model's first few hundred runs are slower
                run_robot(args, "ws", 25, f"http://127.0.0.1:{port}", server.pid, variants[name], args.warmup)
        for repeat in range(args.repeat):  # configurations interleaved, so slow drifts hit all of them alike
            for link_name in args.links.split(","):
                with contextlib.ExitStack() as links:
                    urls = {name: links.enter_context(link(link_name, port)) for name, (_, port) in servers.items()}
                    for fps in (float(f) for f in args.fps.split(",")):
                        for transport in transports:
                            for name, (server, _) in servers.items():
                                if transport == "direct" and (link_name != "loopback" or name != next(iter(servers))):
                                    continue  # one direct run for all variants
                                code = variants[name] if transport != "direct" else None
                                row = run_robot(args, transport, fps, urls[name], server.pid, code) | {
                                    "link": link_name,
                                    "variant": name if transport != "direct" else "",
                                }
                                rows.append(row)
                                print(
                                    f"[{repeat + 1}/{args.repeat}] {name:6} {link_name:8} {transport:6} {fps:5g} fps: "
                                    f"{row['results_per_s']:.2f} results/s, p50 {fmt(row['latency_ms']['p50'])} ms, "
                                    f"outside the model {fmt(row['outside_model_ms'])} ms",
                                    file=sys.stderr,
                                    flush=True,
                                )
    rows = merge_repeats(rows)
    report = f"{table(rows)}\n{paper_table(rows)}\n\n{findings(rows)}\n"
    (out_dir / "table.md").write_text(report)
    (out_dir / "runs.json").write_text(json.dumps(rows, indent=1))
    written = plots(rows, out_dir)
    print(report)
    print(f"written: {out_dir}/table.md, runs.json" + "".join(f", {w.name}" for w in written))
    median_direct = (
        statistics.median(r["latency_ms"]["p50"] for r in rows if r["transport"] == "direct")
        if any(r["transport"] == "direct" for r in rows)
        else None
    )
    if median_direct is not None:
        print(f"direct pipeline median latency: {median_direct:.1f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
