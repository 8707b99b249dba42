"""The uplink controller (pure: no I/O, no clock; every call says what time it is).

Each result tells it the frame's bytes and its latency parts; from them it estimates the uplink
(`netapp.client.adapt.estimate`) and chooses what the next frames are sent with (a `Choice`: a ladder rung, its
codec and, for H.264, a bitrate, a frame rate). Where the transport carries both codecs (`switch_codec`), the
ladder's cheapest rungs are H.264 ones below JPEG's (`ladder.py`): the codec is chosen as any rung is, by the bytes
that fit, so it changes between frames where the uplink gets too thin for JPEG above the floor, and back. Its
rules, in order:

1. **The latency budget first.** A frame may take `headroom` of the budget, less what the netapp takes (but at
   least `min_uplink_share` of it: the uplink is not to blame for a queue at the netapp) and the round trip's
   fixed delay, and the frames together `headroom` of the uplink's rate. The allowance is the bytes that fit
   both.
2. **Step down at once.** When the rung in use does not fit the allowance (the estimate drops after two slow
   results, or one `SURE_LATE` times over the budget), the controller goes straight to the highest rung that
   fits; two results over the budget in a row, or two frames missed, step down one rung even when the estimate
   says they fit (not when the netapp's own queue made them late, and never the frame rate: that answers the
   uplink's measured rate alone).
3. **Never below the floor.** The ladder holds no rung below the accuracy floor; when even its cheapest rung does
   not fit the uplink's rate, the frame rate goes down instead (never below `min_fps`).
4. **Probe up carefully.** After `hold_s` without a change or a miss, one step up (the frame rate back first, then
   one rung), only when the next rung fits in `up_margin` of the allowance (the hysteresis between stepping down
   and up). A probe that misses within `probe_window_s`, or whose results come `probe_rise_ms` later than before it
   (more than its bigger frames explain: the link's queue grows before any result is late; a token bucket's burst
   hides a rate for a second or more), goes back down and doubles the hold (up to `max_hold_s`); one that holds
   resets it.
5. **Spend nothing above the knee.** The ladder's top is the cheapest rung as good as the best (`ladder.py`).

Only results of frames sent with the current choice can change it (those sent before are already answered by the
change), but all of them teach the estimate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from netapp.accuracy import DEFAULT_F1_FLOOR
from netapp.client.adapt.admission import admits, predicted_latency_ms
from netapp.client.adapt.estimate import UplinkEstimate
from netapp.client.adapt.ladder import H264_JPEG_RATIO, Ladder

DEFAULT_BUDGET_MS = 150.0  # 3GPP's packet delay budget for conversational video (TS 23.501, 5QI 2)
# A result this many times the budget is the link, not jitter (5G's is +-4 ms a way; a netapp's own queue is taken out
# of the rate's sample): its rate is taken at once. 3, then 2, let a fall from 4 to 0.25 Mbit/s wait for a second slow
# result (the first 250 ms), and a 12 KB frame went behind the first meanwhile, late by 0.6 s.
SURE_LATE = 1.5
MAX_VERSIONS = 64  # choices remembered, to know which one a result's frame was sent with
H264_RUNG_JPEG_QUALITY = 85  # an H.264 rung's JPEG quality (unused: JPEG bytes a robot sends go as they are)


@dataclass(frozen=True)
class AdaptConfig:
    """The controller's knobs; the defaults are the ones `NetAppClient(adapt="auto")` uses."""

    latency_budget_ms: float = DEFAULT_BUDGET_MS
    accuracy_floor: float = DEFAULT_F1_FLOOR  # no rung below it (`Ladder.from_profile`)
    source_fps: float = 10.0
    codec: str = "jpeg"  # the transport's own; "h264": a bitrate beside the rung
    switch_codec: bool = False  # the transport carries both: H.264 rungs (the profile's) below JPEG's
    headroom: float = 0.8  # share of the budget and of the uplink rate that frames may use
    min_uplink_share: float = 0.3  # of the budget, kept for the uplink whatever the netapp takes
    up_margin: float = 0.8  # a step up only when the next rung fits in this share of the allowance
    hold_s: float = 2.0  # stable this long before a step up
    max_hold_s: float = 30.0
    probe_window_s: float = 3.0  # a step up that keeps the budget this long has held (a burst's bytes drained)
    probe_rise_ms: float = 20.0  # a step up whose results come this much later than before it has failed
    min_fps: float = 1.0
    start_rung: int | None = None  # None: the cheapest JPEG one (start safe, probe up; H.264 once JPEG won't fit)

    def __post_init__(self) -> None:
        if not self.latency_budget_ms > 0:
            raise ValueError("the latency budget must be positive")
        if not self.source_fps > 0:
            raise ValueError("the source's frame rate must be positive")
        if not 0 <= self.accuracy_floor <= 1:
            raise ValueError("the accuracy floor is an F1, in 0..1")
        if self.codec not in ("jpeg", "h264"):
            raise ValueError(f"codec must be jpeg or h264, got {self.codec!r}")


@dataclass(frozen=True)
class Choice:
    """What the next frames are sent with."""

    long_side: int | None  # pixels of the frame's longer side (None: the source's own)
    jpeg_quality: int
    bitrate_kbps: int | None  # H.264 only
    fps: float
    rung: int  # index in the ladder
    version: int  # increases with every change; a frame carries the version it was sent with
    reason: str = "start"
    codec: str | None = None  # chosen frame by frame (`AdaptConfig.switch_codec`); None: the transport's own

    def settings(self) -> dict[str, object]:
        """The choice as plain data (the summary's and the JSON's form)."""
        return {
            "codec": self.codec,
            "long_side": self.long_side,
            "jpeg_quality": self.jpeg_quality,
            "bitrate_kbps": self.bitrate_kbps,
            "fps": round(self.fps, 2),
        }


@dataclass(frozen=True)
class Observation:
    """One result, as the controller needs it (milliseconds; times in seconds on the caller's clock)."""

    t_s: float  # when the result arrived
    version: int  # the `Choice.version` its frame was sent with
    bytes_sent: int
    latency_ms: float  # the robot's send to its receipt
    netapp_ms: float  # queue + inference, on the netapp's clock (`LatencyBreakdown`)


class Controller:
    """Chooses send settings from observations (see the module). Not thread-safe: one caller at a time."""

    def __init__(self, ladder: Ladder, config: AdaptConfig | None = None) -> None:
        self.ladder = ladder
        self.config = config or AdaptConfig()
        self.estimate = UplinkEstimate()
        start = self.config.start_rung if self.config.start_rung is not None else self._first_jpeg_rung()
        rung = min(max(0, start), ladder.top)
        self._rung_of: dict[int, int] = {0: rung}
        self.choice = self._make(rung, self.config.source_fps, 0, "start")
        self._changed_at: float | None = None  # None: nothing yet (the hold counts from the first observation)
        self._trouble_at: float | None = None  # the last result over budget, or miss
        self._over = 0  # fresh results over the budget in a row
        self._misses = 0  # frames missed in a row
        self._hold_s = self.config.hold_s
        self._probe_from: int | None = None  # the rung a step up left, while it is on probation
        self._probe_fps: float | None = None
        self._probe_limit_ms: float | None = None  # a result of the probe later than this fails it

    def _first_jpeg_rung(self) -> int:
        """Where a start without a rung starts: the cheapest, or JPEG's cheapest where the ladder holds H.264 below
        it (JPEG until the uplink is known to be too thin for it)."""
        if not self.config.switch_codec:
            return 0  # one codec: its cheapest (on an H.264 transport, the profile's H.264 rows come first)
        return next((i for i, r in enumerate(self.ladder.rungs) if r.codec == "jpeg"), 0)

    # -- inputs ----------------------------------------------------------------------------------------------------

    def observe(self, obs: Observation) -> Choice | None:
        """A result arrived; the new choice when it changes, else None."""
        if self._changed_at is None:
            self._changed_at = obs.t_s
        rung = self._rung_of.get(obs.version)
        if rung is not None:
            predicted = self._profile_bytes(rung)
            sure = obs.latency_ms > SURE_LATE * self.config.latency_budget_ms
            codec = self.ladder.rungs[rung].codec if self.config.switch_codec else None
            end_ms = obs.t_s * 1000.0 - obs.netapp_ms
            self.estimate.add(obs.bytes_sent, obs.latency_ms, obs.netapp_ms, predicted, sure, codec, end_ms)
        self._misses = 0
        if obs.version != self.choice.version:
            return None  # sent before the last change: that change already answered it
        budget = self.config.latency_budget_ms
        # Over the budget by the uplink's fault: a netapp whose queue takes more than the uplink's share leaves it
        # to the estimate (smaller frames would not make such results timely).
        over = obs.latency_ms > budget and obs.netapp_ms < budget * (1 - self.config.min_uplink_share)
        self._over = self._over + 1 if over else 0
        if over:
            self._trouble_at = obs.t_s
        return self._decide(obs.t_s, obs.latency_ms)

    def missed(self, t_s: float) -> Choice | None:
        """A frame got no result in time (lost, or dropped by the netapp for its deadline)."""
        self._trouble_at = t_s
        self._misses += 1
        if self._misses >= 2:
            self._misses = 0
            return self._step_down(t_s, "frames missed")
        return None

    def admits(self, t_s: float, in_flight: Sequence[tuple[float, int]]) -> bool:
        """Whether the next frame can make the budget at `t_s` behind the frames in flight ((sent at, bytes), oldest
        first): `netapp.client.adapt.admission`."""
        est, now = self.estimate, self.choice
        return admits(
            t_s,
            in_flight,
            self.predicted_bytes(now.rung),
            self.config.latency_budget_ms,
            est.rate_bytes_per_ms,
            est.link_free_s,
            est.round_trip_ms,
            est.netapp_ms,
        )

    def predicted_latency_ms(self, t_s: float, in_flight: Sequence[tuple[float, int]], frame_bytes: int) -> float:
        """The latency a frame of `frame_bytes` sent at `t_s` behind `in_flight` should see (0: nothing known)."""
        est = self.estimate
        rate, free = est.rate_bytes_per_ms, est.link_free_s
        if rate is None or rate <= 0:
            return 0.0
        return predicted_latency_ms(
            t_s, in_flight, frame_bytes, rate, free if free is not None else t_s, est.round_trip_ms, est.netapp_ms
        )

    def set_source_fps(self, fps: float) -> None:
        """The robot's frames come at `fps` (measured): a full frame rate follows it, a lowered one stays."""
        old = self.config.source_fps
        self.config = replace(self.config, source_fps=fps)
        if self.choice.fps >= old * 0.99 or self.choice.fps > fps:
            self.choice = replace(self.choice, fps=fps)

    # -- decisions -------------------------------------------------------------------------------------------------

    def allowance(self, fps: float) -> float | None:
        """Bytes a frame may take at `fps` (None before the first estimate)."""
        cfg, est = self.config, self.estimate
        rate = est.rate_bytes_per_ms
        if rate is None:
            return None
        budget = cfg.latency_budget_ms
        network_ms = max(budget * cfg.headroom - est.netapp_ms, budget * cfg.min_uplink_share)
        by_latency = max(0.0, network_ms - est.round_trip_ms) * rate
        by_rate = cfg.headroom * rate * 1000.0 / fps
        return min(by_latency, by_rate)

    def predicted_bytes(self, rung: int) -> float:
        """A rung's bytes per frame on this robot: the profile's, scaled by what was measured."""
        codec = self.ladder.rungs[rung].codec if self.config.switch_codec else None
        return self._profile_bytes(rung) * self.estimate.scale_of(codec)

    def _profile_bytes(self, rung: int) -> float:
        step = self.ladder.rungs[rung]
        # An H.264 transport with the profile's JPEG rows only: what those frames would take as H.264, roughly.
        ratio = H264_JPEG_RATIO if self.config.codec == "h264" and step.codec == "jpeg" else 1.0
        return step.bytes_per_frame * ratio

    def _fitting(self, allowance: float) -> int | None:
        fits = [i for i in range(len(self.ladder)) if self.predicted_bytes(i) <= allowance]
        return max(fits) if fits else None

    def _decide(self, t: float, latency_ms: float = 0.0) -> Choice | None:
        cfg, now = self.config, self.choice
        allowance = self.allowance(now.fps)
        if allowance is None:
            return None
        target = self._fitting(allowance)
        if self._probe_from is not None:  # a step up on probation
            risen = self._probe_limit_ms is not None and latency_ms > self._probe_limit_ms
            if self._over > 0 or risen or (target is not None and target < now.rung) or self._fps_short(now.fps):
                return self._fail_probe(t, target)
            if t - self._changed_at >= cfg.probe_window_s:  # type: ignore[operator]
                self._probe_from = self._probe_fps = None
                self._hold_s = cfg.hold_s
        if target is None:  # even the cheapest rung does not fit: the frame rate gives way
            fps = self._affordable_fps()
            if now.rung > 0 or fps < now.fps * 0.9:
                return self._change(t, 0, fps, "uplink: the cheapest rung does not fit, fewer fps")
            return None
        if target < now.rung:
            return self._change(t, target, now.fps, "uplink slower")
        if self._over >= 2:
            return self._step_down(t, "over the latency budget")
        if self._stable(t):
            return self._probe_up(t)
        return None

    def _fps_short(self, fps: float) -> bool:
        """The frame rate no longer fits even the cheapest rung."""
        return self._affordable_fps() < fps * 0.9

    def _affordable_fps(self) -> float:
        rate = self.estimate.rate_bytes_per_ms or 0.0
        fps = self.config.headroom * rate * 1000.0 / self.predicted_bytes(0)
        return min(self.config.source_fps, max(self.config.min_fps, fps))

    def _stable(self, t: float) -> bool:
        since = max(self._changed_at or t, self._trouble_at or -1e18)
        return t - since >= self._hold_s

    def _probe_up(self, t: float) -> Choice | None:
        cfg, now = self.config, self.choice
        if now.fps < cfg.source_fps:  # the frame rate comes back before any quality
            fps = min(cfg.source_fps, now.fps * 1.5)
            allowance = self.allowance(fps)
            if allowance is not None and self.predicted_bytes(0) <= allowance * cfg.up_margin:
                return self._probe(t, now.rung, fps)
            return None
        if now.rung >= self.ladder.top:
            return None
        allowance = self.allowance(now.fps)
        if allowance is not None and self.predicted_bytes(now.rung + 1) <= allowance * cfg.up_margin:
            return self._probe(t, now.rung + 1, now.fps)
        return None

    def _probe(self, t: float, rung: int, fps: float) -> Choice:
        self._probe_from, self._probe_fps = self.choice.rung, self.choice.fps
        self._probe_limit_ms = self._probe_limit(rung, fps)
        return self._change(t, rung, fps, "probe up")

    def _probe_limit(self, rung: int, fps: float) -> float | None:
        """The latency a probe's result may take: the recent median, plus the bigger frame's bytes at the estimated
        rate, plus `probe_rise_ms` (None: nothing known yet)."""
        est, now = self.estimate, self.choice
        if est.latency_ms is None or not est.rate_bytes_per_ms:
            return None
        more = max(0.0, self.predicted_bytes(rung) - self.predicted_bytes(now.rung)) / est.rate_bytes_per_ms
        return est.latency_ms + more + self.config.probe_rise_ms

    def _fail_probe(self, t: float, target: int | None) -> Choice:
        back, fps = self._probe_from, self._probe_fps
        self._probe_from = self._probe_fps = None
        self._hold_s = min(self._hold_s * 2, self.config.max_hold_s)
        rung = min(back if back is not None else 0, target if target is not None else 0)
        return self._change(t, rung, min(fps or self.config.source_fps, self._affordable_fps()), "probe failed")

    def _step_down(self, t: float, reason: str) -> Choice | None:
        now = self.choice
        self._over = 0
        if self._probe_from is not None:
            return self._fail_probe(t, now.rung - 1)
        if now.rung > 0:
            return self._change(t, now.rung - 1, now.fps, reason)
        return None  # the frame rate answers the uplink's rate alone (a queue at the netapp is not the uplink's)

    def _change(self, t: float, rung: int, fps: float, reason: str) -> Choice:
        version = self.choice.version + 1
        self.choice = self._make(rung, fps, version, reason)
        self._rung_of[version] = rung
        while len(self._rung_of) > MAX_VERSIONS:
            del self._rung_of[min(self._rung_of)]
        self._changed_at = t
        self._over = 0
        return self.choice

    def _make(self, rung: int, fps: float, version: int, reason: str) -> Choice:
        step = self.ladder.rungs[rung]
        codec = step.codec if self.config.switch_codec else None
        bitrate = None
        if step.bitrate_kbps is not None:  # the profile's bitrate (its F1 is that of the frames it gave), per frame
            bitrate = max(1, round(step.bitrate_kbps * fps / self.ladder.fps))
        elif (codec or self.config.codec) == "h264":  # the rung's bytes at this frame rate, as bits per second
            bitrate = max(1, round(self.predicted_bytes(rung) * fps * 8 / 1000))
        quality = step.quality if step.codec == "jpeg" else H264_RUNG_JPEG_QUALITY
        return Choice(step.long_side, quality, bitrate, fps, rung, version, reason, codec)
