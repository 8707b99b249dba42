"""Whether decoding keeps up with a camera: how far its decoded pictures fall behind the camera's own clock. Pure.

A camera sends in real time, so (arrival time - picture time) stays about constant while the netapp keeps up; it grows
when decoding is slower than the camera (TCP holds the rest back; over UDP the socket's buffer overflows and pictures
arrive damaged). The smallest offset seen is the baseline: a picture that comes later than that by more than
MAX_BEHIND_S means the decoder is behind, and the reader drops to keyframes only.
"""

from __future__ import annotations

from dataclasses import dataclass

MAX_BEHIND_S = 2.0  # a loaded machine's hiccups stay under it; a decoder that cannot keep up passes it in seconds


@dataclass
class KeepingUp:
    baseline: float | None = None  # the smallest (arrival - picture time) seen, seconds
    last_time: float | None = None  # the previous picture's time

    def behind_s(self, now_s: float, picture_s: float | None) -> float:
        """Seconds the picture of time `picture_s` (the stream's clock), decoded at `now_s`, is behind the best
        seen; 0 for a picture without a time, or when the stream's clock went back (a restarted camera)."""
        if picture_s is None:
            return 0.0
        if self.last_time is not None and picture_s < self.last_time:
            self.baseline = None
        self.last_time = picture_s
        offset = now_s - picture_s
        if self.baseline is None or offset < self.baseline:
            self.baseline = offset
        return offset - self.baseline

    def restart(self) -> None:
        """The camera paused (no packet for a while): a new baseline, from the pictures after it."""
        self.baseline = self.last_time = None

    def cannot_keep_up(self, now_s: float, picture_s: float | None) -> bool:
        return self.behind_s(now_s, picture_s) > MAX_BEHIND_S
