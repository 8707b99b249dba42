"""bench/robots.py's figures: each robot's results/s in the window every robot streamed in, the priority classes'
shares and deadline misses, and the tables of table.md."""

from __future__ import annotations

import statistics


def window_rates(arrivals: list[list[float]]) -> list[float]:
    """Each robot's results/s while every robot was getting results: from the last robot's first result to the
    first robot's last one (robots that start together connect over a second or more: a robot's rate over its own
    time would count the seconds it had the netapp to fewer robots). Within it, a robot's rate is its results'
    intervals over their span (counting results would favour the robots whose results open or close the window).
    A robot that got none: 0."""
    if not all(arrivals):
        return [_rate(a) for a in arrivals]
    begin, end = max(a[0] for a in arrivals), min(a[-1] for a in arrivals)
    return [_rate([t for t in a if begin <= t <= end]) for a in arrivals]


def _rate(arrivals: list[float]) -> float:
    """Results per second from result times (sorted): the intervals over their span."""
    if len(arrivals) < 2:
        return 0.0
    return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])


def class_figures(summaries: list[dict]) -> dict[str, dict]:
    """Per priority class: robots, results/s per robot, share of all results, and the deadline misses: frames
    sent that got no result within the deadline (late, dropped for it, superseded or lost), % of frames sent."""
    total = sum(s["results"] for s in summaries) or 1
    figures = {}
    for name in sorted({s["priority"] for s in summaries}):
        mine = [s for s in summaries if s["priority"] == name]
        sent = sum(s["frames_sent"] for s in mine)
        on_time = sum(s["within_deadline"] for s in mine)
        latencies = sorted(v for s in mine for v in s["latencies_ms"])
        figures[name] = {
            "robots": len(mine),
            "results_per_s_each": statistics.fmean(s["results_per_s"] for s in mine),
            "share": sum(s["results"] for s in mine) / total,
            "within_deadline_per_s": sum(s["within_deadline_per_s"] for s in mine),
            "missed_pct": 100 * (sent - on_time) / sent if sent else 0.0,
            "p50": pct(latencies, 50),
            "p95": pct(latencies, 95),
        }
    return figures


def pct(values: list[float], q: float) -> float | None:
    from netapp.client.stats import percentile

    return percentile(values, q) if values else None


def table(rows: list[dict], maximum: float, fps: float) -> str:
    head = (
        "| variant | replicas | robots | input results/s | frames sent/s | results/s | % of max | % of input "
        "| share min | share max | fairness | p50 ms | p95 ms | lost | errors | replica CPU % | robots CPU % "
        "| estimated capacity results/s | slowest first result s |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        offered = r["robots"] * fps
        lines.append(
            f"| {r['variant']} | {r['replicas']} | {r['robots']} | {offered:g} | {r['sent_per_s']:.1f} | "
            f"{r['results_per_s']:.1f} | "
            f"{100 * r['results_per_s'] / maximum:.0f} | {100 * r['results_per_s'] / offered:.0f} | "
            f"{r['share_min']:.2f} | {r['share_max']:.2f} | {r['fairness']:.2f} | {r['p50']:.1f} | {r['p95']:.1f} | "
            f"{r['lost']} | {r['errors']} | {' + '.join(f'{c:.0f}' for c in r['server_cpu'])} | "
            f"{r['robots_cpu']:.0f} | "
            f"{'-' if r['estimated_capacity'] is None else round(r['estimated_capacity'], 1)} | "
            f"{r['first_result_s']:.1f} |"
        )
    return "\n".join(lines)


def class_table(rows: list[dict]) -> str:
    """The priority classes of each row (--priorities): who got what, and the deadlines missed."""
    head = (
        "| variant | robots | aggregate results/s | within deadline/s | class | robots in it | results/s each "
        "| share of results | deadline missed % | p50 ms | p95 ms |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        within = sum(c["within_deadline_per_s"] for c in r["classes"].values())
        for name, c in r["classes"].items():
            lines.append(
                f"| {r['variant']} | {r['robots']} | {r['results_per_s']:.1f} | {within:.1f} | {name} | {c['robots']} "
                f"| {c['results_per_s_each']:.1f} | {100 * c['share']:.0f} % | {c['missed_pct']:.1f} "
                f"| {c['p50']:.0f} | {c['p95']:.0f} |"
            )
    return "\n".join(lines)
