"""A deterministic uplink for the controller's pure tests: frames queue on one link of a given rate (a function of
time), then a fixed delay, a netapp that takes `inference_ms`, and the same delay back. No clock, no sockets. The
frame rate is kept as the adapter keeps it (`rate_admits`); `spread` varies each frame's bytes about its rung's as a
video's P-frames and keyframes do."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from netapp.client.adapt import Choice, Controller, Observation
from netapp.client.adapt.adapter import RATE_SLACK, rate_admits
from netapp.client.adapt.admission import overdue


@dataclass
class Trace:
    """What happened: every choice (time, choice), every result (arrival time, latency ms, bytes, version)."""

    choices: list[tuple[float, Choice]] = field(default_factory=list)
    results: list[tuple[float, float, int, int]] = field(default_factory=list)

    def changes_between(self, start: float, end: float) -> list[tuple[float, Choice]]:
        return [(t, c) for t, c in self.choices if start <= t < end]


def simulate(
    controller: Controller,
    rate_mbit: Callable[[float], float],
    duration_s: float,
    delay_ms: float = 10.0,
    inference_ms: float = 20.0,
    max_in_flight: int = 2,
    byte_scale: float = 1.0,
    spread: Callable[[int], float] = lambda i: 1.0,
    burst_bytes: int = 0,
) -> Trace:
    """Stream `duration_s` of a camera at the controller's source fps through the link; `burst_bytes`: the link is a
    token bucket that holds this many bytes (the link emulator's tbf holds 16 KB): within them a frame goes at once,
    so its latency says nothing of the rate until the bucket is empty."""
    trace = Trace(choices=[(0.0, controller.choice)])
    period = 1.0 / controller.config.source_fps
    pending: list[tuple[float, Observation, float, float]] = []  # (arrives, result, sent at, predicted latency ms)
    link_free = 0.0
    tokens, tokens_at = float(burst_bytes), 0.0
    due: float | None = None
    waiting: float | None = None  # a frame offered (when) that waits for a slot, as in the sender's ledger
    ms, index = 0, 0
    while ms < duration_s * 1000:
        t = ms / 1000
        for arrived, obs, sent, predicted in sorted((p for p in pending if p[0] <= t), key=lambda p: (p[0], p[2])):
            pending.remove((arrived, obs, sent, predicted))
            trace.results.append((arrived, obs.latency_ms, obs.bytes_sent, obs.version))
            change = controller.observe(obs)
            if change is not None:
                trace.choices.append((arrived, change))
        choice = controller.choice
        in_flight = sorted((sent, o.bytes_sent) for _, o, sent, _ in pending)
        if ms % round(period * 1000) == 0 and controller.admits(t, in_flight):  # the adapter's `admit`
            go, due = rate_admits(t, due, 1.0 / choice.fps, RATE_SLACK * period)
            if go:
                waiting = t  # an older frame waiting is dropped for this one
        late = overdue(t, [(sent, predicted) for _, _, sent, predicted in pending], controller.config.latency_budget_ms)
        cap = min(max_in_flight, len(pending) if late else max_in_flight)  # the adapter's `in_flight_cap`
        if waiting is not None and len(pending) < cap:
            offered, waiting = waiting, None
            rung = controller.ladder.rungs[choice.rung]
            size = int(rung.bytes_per_frame * byte_scale * spread(index))  # an H.264 rung's: its measured bytes
            index += 1
            if choice.bitrate_kbps is not None and rung.bitrate_kbps is None:  # JPEG's rung as H.264: the bitrate's
                size = int(choice.bitrate_kbps * 1000 / 8 / choice.fps)
            start = max(t, link_free)
            bytes_per_s = rate_mbit(start) * 1e6 / 8
            tokens = min(float(burst_bytes), tokens + (start - tokens_at) * bytes_per_s)
            paid = min(tokens, float(size))
            link_free = start + (size - paid) / bytes_per_s  # beyond the tokens, at the rate (each spent as it comes)
            tokens, tokens_at = tokens - paid, link_free
            uplink_ms = (link_free - offered) * 1000 + delay_ms
            latency_ms = uplink_ms + inference_ms + delay_ms
            obs = Observation(offered + latency_ms / 1000, choice.version, size, latency_ms, inference_ms)
            predicted = controller.predicted_latency_ms(t, in_flight, size) or controller.config.latency_budget_ms
            pending.append((obs.t_s, obs, t, predicted))
        ms += 1
    return trace
