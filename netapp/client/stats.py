"""Client-side counters and the latency summary (pure)."""

from __future__ import annotations

import statistics
import threading
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from netapp.client.timing import PARTS, LatencyBreakdown
from netapp.detections import Detections, as_detections


def percentile(values: list[float], q: float) -> float:
    """Nearest-rank percentile; NaN for no values."""
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q / 100 * len(ordered) + 0.5) - 1))]


@dataclass
class ClientStats:
    """What a robot sent and got back. Thread-safe counters, latencies in milliseconds."""

    offered: int = 0  # frames handed to send()
    sent: int = 0  # frames put on the wire
    results: int = 0
    dropped_client: int = 0  # superseded before sending (newest wins)
    dropped_server: int = 0  # superseded in the server's queue
    lost: int = 0  # sent, but no result in time or the connection dropped
    errors: int = 0
    moves: int = 0  # times a draining netapp told this robot to move, and it reconnected through the Service
    late: int = 0  # results that arrived after the deadline (counted in `results` too)
    deadline_dropped: int = 0  # dropped by a netapp before inference: it could not meet the deadline
    discarded: int = 0  # hedged: results of a frame another netapp (or the fallback) answered first
    switches: int = 0  # changes of what the client does (netapps used, hedging, fallback)
    by_source: Counter = field(default_factory=Counter)  # results kept, by netapp URL or "local"
    bytes_sent: int = 0
    frame_size: tuple[int, int] | None = None  # (width, height) of the first frame sent as an array
    sent_size: tuple[int, int] | None = None  # (width, height) the latest frame went on the wire at
    bad_hints: int = 0  # malformed hints from netapps, ignored (`netapp.client.hints`)
    checkpoints: int = 0  # session-state checkpoints received from a stateful netapp
    restores: int = 0  # a new session got the latest checkpoint back (a move, a reconnect)
    latencies_ms: list[float] = field(default_factory=list)
    parts_ms: dict[str, list[float]] = field(default_factory=lambda: {p: [] for p in PARTS})
    classes: Counter = field(default_factory=Counter)
    last_error: str | None = None
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add(self, **counts: int) -> None:
        with self.lock:
            for name, n in counts.items():
                setattr(self, name, getattr(self, name) + n)

    def add_result(
        self,
        latency_ms: float,
        detections: Detections | list[Any],
        source: str | None = None,
        late: bool = False,
        breakdown: LatencyBreakdown | None = None,
    ) -> None:
        with self.lock:
            self.results += 1
            self.late += late
            self.latencies_ms.append(latency_ms)
            if breakdown is not None:
                for part in PARTS:
                    self.parts_ms[part].append(getattr(breakdown, part))
            typed = as_detections(detections)
            self.classes.update(typed.class_text(i) for i in range(len(typed)))
            if source is not None:
                self.by_source[source] += 1

    def summary(self, elapsed_s: float) -> dict[str, Any]:
        with self.lock:
            lat = list(self.latencies_ms)
            parts = {p.removesuffix("_ms"): round(statistics.median(v), 1) for p, v in self.parts_ms.items() if v}
            return {
                "duration_s": round(elapsed_s, 2),
                "frames_offered": self.offered,
                "frames_sent": self.sent,
                "frame_size": f"{self.frame_size[0]}x{self.frame_size[1]}" if self.frame_size else None,
                "sent_size": f"{self.sent_size[0]}x{self.sent_size[1]}" if self.sent_size else None,
                "results": self.results,
                "results_per_s": round(self.results / elapsed_s, 2) if elapsed_s > 0 else 0.0,
                "latency_ms": {
                    "p50": round(percentile(lat, 50), 1) if lat else None,
                    "p95": round(percentile(lat, 95), 1) if lat else None,
                    "max": round(max(lat), 1) if lat else None,
                    "mean": round(statistics.fmean(lat), 1) if lat else None,
                },
                # medians of each part (they need not add up to the median total)
                "latency_breakdown_ms": parts or None,
                "dropped": {"client": self.dropped_client, "server": self.dropped_server},
                "within_deadline": self.results - self.late,
                "within_deadline_per_s": round((self.results - self.late) / elapsed_s, 2) if elapsed_s > 0 else 0.0,
                "late": self.late,
                "deadline_dropped": self.deadline_dropped,
                "discarded": self.discarded,
                "switches": self.switches,
                "by_source": dict(self.by_source),
                "lost": self.lost,
                "errors": self.errors,
                "moves": self.moves,
                "last_error": self.last_error,
                "bytes_per_frame": round(self.bytes_sent / self.sent) if self.sent else 0,
                "bad_hints": self.bad_hints,
                "detections": dict(self.classes.most_common(8)),
            }


def no_results_line(summary: dict[str, Any]) -> str:
    """Why a stream got no result, in one line (`netapp stream` exits 1 then): what went out, what came back instead,
    and the transport's own counters where it keeps some (`transport_counters`: RTP's packets, NACKs, PLIs, results
    by path)."""
    dropped = summary["dropped"]
    line = (
        f"no results: {summary['frames_sent']} of {summary['frames_offered']} frames sent, {summary['errors']} errors, "
        f"{summary['lost']} lost, dropped {dropped['client']} by the robot and {dropped['server']} by the netapp"
    )
    for url, counters in (summary.get("transport_counters") or {}).items():
        line += f"; {url}: " + ", ".join(f"{name} {value}" for name, value in counters.items() if value is not None)
    last = summary.get("last_error")
    return line + (f"; the last error: {last}" if last else "; no error came back: see the netapp's log")


def format_summary(summary: dict[str, Any]) -> str:
    """The summary for a person. Optional keys the caller may add: url or urls (and policy), transport, fps,
    processor, recording (topic, frames, skipped by reason)."""
    lat = summary["latency_ms"]
    detections = ", ".join(f"{name} x{n}" for name, n in summary["detections"].items()) or "none"
    if lat["p50"] is None:
        latency = "no results"
    else:
        latency = f"p50 {lat['p50']} ms, p95 {lat['p95']} ms, max {lat['max']} ms"
    parts = summary.get("latency_breakdown_ms")
    sources = ", ".join(f"{source} x{n}" for source, n in summary["by_source"].items()) or "none"
    lines = []
    urls = summary.get("urls") or ([summary["url"]] if summary.get("url") else [])
    if len(urls) == 1:
        lines.append(f"netapp          {urls[0]}")
    elif urls:
        lines.append(f"netapps         {', '.join(urls)} (policy {summary.get('policy') or 'primary'})")
    if summary.get("processor"):
        lines.append(f"processor       {summary['processor']}")
    if summary.get("recording"):
        played = summary["recording"]
        skipped = "; ".join(f"{reason} x{n}" for reason, n in played["skipped"].items())
        lines.append(
            f"recording       {played['topic']}: {played['frames']} frames"
            + (f", skipped {skipped}" if skipped else "")
        )
    if summary.get("transport"):
        size = summary.get("frame_size") or "as sent"
        sent = summary.get("sent_size")
        sent = f", sent at {sent}" if sent and sent != size else ""
        fps = f" at {summary['fps']:g} fps" if summary.get("fps") else ""
        lines.append(f"transport       {summary['transport']}, frames {size}{sent}{fps}")
    lines += [
        f"duration        {summary['duration_s']} s",
        f"frames sent     {summary['frames_sent']} of {summary['frames_offered']} offered",
        f"results         {summary['results']} ({summary['results_per_s']} per second)",
        f"latency         {latency}",
    ]
    if parts:
        lines.append(
            f"  median parts  uplink {parts['uplink']} ms, queue {parts['queue']} ms, "
            f"inference {parts['inference']} ms, downlink {parts['downlink']} ms"
        )
    lines += [
        f"dropped         {summary['dropped']['client']} before sending, {summary['dropped']['server']} by the server "
        "(newest frame wins)",
        f"deadline        {summary['within_deadline']} within ({summary['within_deadline_per_s']} per second), "
        f"{summary['late']} late, {summary['deadline_dropped']} dropped by a netapp before inference",
        f"by source       {sources}; {summary['discarded']} hedged results discarded, {summary['switches']} switches",
        f"lost / errors   {summary['lost']} / {summary['errors']}"
        + (f" (last: {summary['last_error']})" if summary["last_error"] else ""),
        *(
            [f"moves           {summary['moves']} (a draining netapp sent the robot elsewhere)"]
            if summary["moves"]
            else []
        ),
        f"bytes per frame {summary['bytes_per_frame']}",
        *([adapt_line(summary["adapt"])] if summary.get("adapt") else []),
        f"detections      {detections}",
    ]
    if summary.get("outputs"):
        lines.append(f"last output     {summary['outputs']}")
    return "\n".join(lines)


def adapt_line(adapt: dict[str, Any]) -> str:
    """The uplink's adaptation in one line (`NetAppClient.adapt_report`)."""
    s = adapt.get("settings") or {}
    now = (
        f"long side {s.get('long_side') or 'as sent'}, JPEG quality {s.get('jpeg_quality')}"
        + (f", {s['bitrate_kbps']} kbit/s" if s.get("bitrate_kbps") else "")
        + f", {s.get('fps')} fps"
        if s
        else "no frame yet"
    )
    share = adapt.get("within_budget")
    within = f"{100 * share:.0f} % of results within it" if share is not None else "no results"
    return (
        f"uplink adapts   budget {adapt['latency_budget_ms']:g} ms ({within}), F1 floor {adapt['accuracy_floor']:g}; "
        f"now {now}; {adapt['change_count']} changes, {adapt['skipped_for_rate']} frames skipped for the rate"
    )


def progress_line(elapsed_s: float, stats: ClientStats) -> str:
    with stats.lock:
        recent = stats.latencies_ms[-50:]
        results, sent, dropped = stats.results, stats.sent, stats.dropped_client + stats.dropped_server
    rate = results / elapsed_s if elapsed_s > 0 else 0.0
    p50 = f"{percentile(recent, 50):.0f} ms" if recent else "-"
    return f"[{elapsed_s:5.1f}s] sent {sent}  results {results} ({rate:.1f}/s)  latency p50 {p50}  dropped {dropped}"
