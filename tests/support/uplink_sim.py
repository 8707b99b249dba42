"""A deterministic uplink for the controller's pure tests: frames queue on one link of a given rate (a function of
time), then a fixed delay, a netapp that takes `inference_ms`, and the same delay back. No clock, no sockets."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from netapp.client.adapt import Choice, Controller, Observation


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
) -> Trace:
    """Stream `duration_s` of a camera at the controller's source fps through the link."""
    trace = Trace(choices=[(0.0, controller.choice)])
    period = 1.0 / controller.config.source_fps
    pending: list[tuple[float, Observation]] = []  # results not yet arrived, by arrival time
    link_free = 0.0
    last_sent = -1e9
    t = 0.0
    while t < duration_s:
        for arrived, obs in sorted(p for p in pending if p[0] <= t):
            pending.remove((arrived, obs))
            trace.results.append((arrived, obs.latency_ms, obs.bytes_sent, obs.version))
            change = controller.observe(obs)
            if change is not None:
                trace.choices.append((arrived, change))
        choice = controller.choice
        if len(pending) < max_in_flight and t - last_sent >= 1.0 / choice.fps - 1e-9:
            last_sent = t
            rung = controller.ladder.rungs[choice.rung]
            size = int(rung.bytes_per_frame * byte_scale)  # an H.264 rung of the profile: its measured bytes
            if choice.bitrate_kbps is not None and rung.bitrate_kbps is None:  # JPEG's rung as H.264: the bitrate's
                size = int(choice.bitrate_kbps * 1000 / 8 / choice.fps)
            start = max(t, link_free)
            link_free = start + size * 8 / (rate_mbit(start) * 1e6)
            uplink_ms = (link_free - t) * 1000 + delay_ms
            latency_ms = uplink_ms + inference_ms + delay_ms
            obs = Observation(t + latency_ms / 1000, choice.version, size, latency_ms, inference_ms)
            pending.append((obs.t_s, obs))
        t = round(t + period, 9)
    return trace
