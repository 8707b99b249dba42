"""`bench/udp.py`'s rounds -> its tables and its plot: pure, apart from writing the PNG.

A row is one (loss, path): several rounds, interleaved with the other paths' so that a change of load on the shared
machine falls on every path alike. p50 and p99 are the medians of the rounds' (a 20 s round at 10 fps has about 200
frames: its p99 is the second-worst frame, so one round alone moves a lot); the range of the rounds' p99s is shown
beside. Where the slowest frames spent their time comes from each result's breakdown (uplink: encode, network and,
for RTP, the netapp waiting for lost packets asked again; queue; inference, decode included; downlink).
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field

PARTS = ("uplink_ms", "queue_ms", "inference_ms", "downlink_ms")
TAIL_SHARE = 0.02  # the slowest 2 % of a row's frames, pooled over its rounds: what its p99 is made of


@dataclass(frozen=True)
class Transport:
    """One path of the table: its name, TCP or UDP (the goal compares the best of each), `netapp stream`'s options."""

    name: str
    kind: str  # "TCP" or "UDP"
    args: tuple[str, ...]


@dataclass
class Round:
    """One `netapp stream` run on one path at one loss."""

    frames_sent: int
    results: int
    results_per_s: float
    latencies: list[float]
    breakdowns: list[dict[str, float]] = field(default_factory=list)
    corrupt: int = 0
    counters: dict[str, float] = field(default_factory=dict)  # the netapp's RTP counters, this round's increase


@dataclass(frozen=True)
class Row:
    loss: float
    path: str
    kind: str
    results_per_s: float
    p50: float
    p99: float
    p99_low: float
    p99_high: float
    unanswered: int
    answered: float
    corrupt: int
    tail: dict[str, float]  # mean of each part over the slowest frames
    counters: dict[str, float]  # summed over the rounds


def percentile(values: Sequence[float], q: float) -> float:
    """The nearest-rank percentile `q` (0..100), NaN for no values."""
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q / 100 * (len(ordered) - 1))))] if ordered else float("nan")


def tail_parts(rounds: Sequence[Round], share: float = TAIL_SHARE) -> dict[str, float]:
    """The mean breakdown of the slowest `share` of the frames that have one, pooled over `rounds`."""
    timed = sorted((b for r in rounds for b in r.breakdowns), key=lambda b: b.get("total_ms", 0.0), reverse=True)
    slowest = timed[: max(1, round(len(timed) * share))] if timed else []
    return {part: statistics.fmean(b.get(part, 0.0) for b in slowest) for part in PARTS} if slowest else {}


def row(loss: float, transport: Transport, rounds: Sequence[Round]) -> Row:
    """One row of the table from its rounds."""
    sent, results = sum(r.frames_sent for r in rounds), sum(r.results for r in rounds)
    p99s = [percentile(r.latencies, 99) for r in rounds]
    counters: dict[str, float] = {}
    for r in rounds:
        for name, value in r.counters.items():
            counters[name] = counters.get(name, 0.0) + value
    return Row(
        loss=loss,
        path=transport.name,
        kind=transport.kind,
        results_per_s=statistics.median(r.results_per_s for r in rounds),
        p50=statistics.median(percentile(r.latencies, 50) for r in rounds),
        p99=statistics.median(p99s),
        p99_low=min(p99s),
        p99_high=max(p99s),
        unanswered=sent - results,
        answered=results / sent if sent else 0.0,
        corrupt=sum(r.corrupt for r in rounds),
        tail=tail_parts(rounds),
        counters=counters,
    )


def best_ratios(rows: Sequence[Row]) -> dict[float, tuple[Row, Row]]:
    """Per loss, (the UDP row with the lowest p99, the TCP row with the lowest p99), where both kinds have rows."""
    out: dict[float, tuple[Row, Row]] = {}
    for loss in sorted({r.loss for r in rows}):
        best = {}
        for kind in ("UDP", "TCP"):
            candidates = [r for r in rows if r.loss == loss and r.kind == kind]
            if candidates:
                best[kind] = min(candidates, key=lambda r: r.p99)
        if len(best) == 2:
            out[loss] = (best["UDP"], best["TCP"])
    return out


def table(rows: Sequence[Row]) -> str:
    """The markdown table docs/benchmarks.md shows, and the goal's ratio per loss below it."""
    lines = [
        "| loss each way | path | results/s | p50 ms | p99 ms | p99 of the rounds | never answered | answered "
        "| corrupt to the model |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.loss:g} % | {r.path} | {r.results_per_s:.1f} | {r.p50:.0f} | {r.p99:.0f} "
            f"| {r.p99_low:.0f}..{r.p99_high:.0f} | {r.unanswered} | {r.answered:.0%} | {r.corrupt} |"
        )
    lines.append("")
    for loss, (udp, tcp) in best_ratios(rows).items():
        lines.append(
            f"{loss:g} %: best UDP p99 / best TCP p99 = {udp.p99 / tcp.p99:.2f} ({udp.path} {udp.p99:.0f} ms, "
            f"{tcp.path} {tcp.p99:.0f} ms; {udp.path} answered {udp.answered:.0%})"
        )
    return "\n".join(lines)


def tail_table(rows: Sequence[Row]) -> str:
    """Where the slowest 2 % of each row's frames spent their time (mean ms per part)."""
    lines = [
        f"| loss each way | path | slowest {TAIL_SHARE:.0%}: total ms | uplink | queue | inference | downlink |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r.tail:
            parts = [r.tail[p] for p in PARTS]
            cells = " | ".join(f"{v:.0f}" for v in parts)
            lines.append(f"| {r.loss:g} % | {r.path} | {sum(parts):.0f} | {cells} |")
    return "\n".join(lines)


def counters_table(rows: Sequence[Row]) -> str:
    """The netapp's RTP and WebRTC counters per row, summed over its rounds (rows without any left out)."""
    names = sorted({name for r in rows for name in r.counters})
    if not names:
        return ""
    lines = ["| loss each way | path | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    for r in rows:
        if r.counters:
            lines.append(
                f"| {r.loss:g} % | {r.path} | " + " | ".join(f"{r.counters.get(n, 0):g}" for n in names) + " |"
            )
    return "\n".join(lines)


def plot(rows: Sequence[Row], path: str, title: str) -> None:
    """p99 (solid) and p50 (dashed) against loss, a colour per path, to a PNG at `path`."""
    import matplotlib

    matplotlib.use("Agg")  # no display: a file only
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(7, 4.2), dpi=110)
    names = list(dict.fromkeys(r.path for r in rows))
    for index, name in enumerate(names):
        mine = sorted((r for r in rows if r.path == name), key=lambda r: r.loss)
        colour = f"C{index}"
        losses = [r.loss for r in mine]
        axes.plot(losses, [r.p99 for r in mine], "o-", color=colour, label=f"{name} p99")
        lows, highs = [r.p99_low for r in mine], [r.p99_high for r in mine]
        axes.fill_between(losses, lows, highs, color=colour, alpha=0.12, label=f"{name} p99, range of the rounds")
        axes.plot(losses, [r.p50 for r in mine], "s--", color=colour, label=f"{name} p50")
    axes.set_xlabel("random loss each way (%)")
    axes.set_ylabel("latency, frame sent to result (ms)")
    axes.set_title(title, fontsize=10)
    axes.set_ylim(bottom=0)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
