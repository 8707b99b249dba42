"""The rungs a controller climbs: an accuracy profile's settings that are worth sending (pure).

From the profile's JPEG (long side, quality) settings the ladder keeps, cheapest first:

* none below the accuracy floor (when none reaches it, the best one alone: the frame rate gives way instead);
* none above the knee: the cheapest setting within `KNEE_TOLERANCE` of the best F1 is the top, since more bytes
  buy no accuracy the profile can tell apart (0.02 F1 is a few boxes in the profile's few hundred);
* only the Pareto front (a setting with more bytes and no better F1 than another is never worth it), thinned so
  each rung costs at least `MIN_STEP` times the one below (steps that small are within a link's noise).

With `h264` (the transport carries both codecs, and the profile has H.264 rows), the H.264 settings' front, built
the same way, goes below: those of its rungs cheaper than JPEG's cheapest above the floor. So JPEG holds wherever it
fits (each frame stands alone: no keyframe to wait for, nothing a lost frame spoils) and H.264 only where bytes are
scarcer than JPEG's floor allows.

A transport of H.264 alone (`jpeg=False`: RTP, or `codec="h264"`) climbs the profile's H.264 front where the profile
measured it, and above its best only JPEG's rungs that are better still, which the controller prices as H.264 roughly
(`H264_JPEG_RATIO` of their bytes: the profile has no H.264 row to say more); a profile without H.264 rows, JPEG's
alone, priced so.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from netapp.accuracy import DEFAULT_F1_FLOOR, AccuracyProfile, Setting

KNEE_TOLERANCE = 0.025  # F1 below the profile's best that is still "as good"
MIN_STEP = 1.2  # bytes of a rung over the one below, at least
H264_JPEG_RATIO = 1 / 3  # an H.264 frame's bytes over a JPEG's of the same picture (docs/client.md#h264)


@dataclass(frozen=True)
class Rung:
    """One setting the controller may choose: a frame's long side (None: the source's own) and JPEG quality (or an
    H.264 bitrate), with the profile's F1 and bytes per frame (at the profile's source size and frame rate)."""

    long_side: int | None
    quality: int
    f1: float
    bytes_per_frame: float
    codec: str = "jpeg"
    bitrate_kbps: int | None = None  # H.264: the profile's, at its frame rate


@dataclass(frozen=True)
class Ladder:
    rungs: tuple[Rung, ...]  # cheapest first; never empty
    floor: float  # the accuracy floor the ladder was built for
    reaches_floor: bool  # False: no setting reaches the floor, the ladder is the best one alone
    fps: float = 10.0  # the profile's H.264 frame rate (a rung's bitrate is for frames at this rate)

    @classmethod
    def from_profile(
        cls,
        profile: AccuracyProfile,
        floor: float = DEFAULT_F1_FLOOR,
        source_long_side: int | None = None,
        max_long_side: int | None = None,
        knee_tolerance: float = KNEE_TOLERANCE,
        min_step: float = MIN_STEP,
        h264: bool = False,
        jpeg: bool = True,
    ) -> Ladder:
        """The ladder of `profile` above `floor`, for a source whose long side is `source_long_side` (a rung never
        asks for more pixels than the source has; None: the profile's source) and a netapp that uses no more than
        `max_long_side` (its processor's input: a setting above it would be sent at it, so it is left out); `h264`:
        the profile's H.264 settings below JPEG's (see the module); `jpeg` False: the transport sends H.264 alone, so
        the H.264 settings are the ladder wherever the profile has them."""
        settings = [_clamped(s, source_long_side) for s in profile.settings]
        if max_long_side is not None:
            whole = source_long_side or max(profile.source_size)
            kept = [s for s in settings if (s.long_side or whole) <= max_long_side]
            settings = kept or settings
        stills = _front([s for s in settings if s.codec == "jpeg"], floor, knee_tolerance, min_step)
        videos = [s for s in settings if s.codec == "h264"]
        video = _front(videos, floor, knee_tolerance, min_step) if h264 or not jpeg else []
        if stills and video and jpeg:
            video = [s for s in video if s.bytes_per_frame < stills[0].bytes_per_frame]
        elif stills and video:  # H.264 alone: JPEG's rungs only above what the H.264 rows measured
            top = video[-1]
            above = top.bytes_per_frame * min_step
            stills = [s for s in stills if s.f1 > top.f1 and s.bytes_per_frame * H264_JPEG_RATIO >= above]
        front = video + stills
        if not front:
            best = max(settings, key=lambda s: (s.codec == "jpeg" or not jpeg, s.f1, -s.bytes_per_frame))
            return cls((_rung(best),), floor, False, profile.fps)
        return cls(tuple(_rung(s) for s in front), floor, True, profile.fps)

    def __len__(self) -> int:
        return len(self.rungs)

    @property
    def top(self) -> int:
        return len(self.rungs) - 1


def _front(settings: list[Setting], floor: float, knee_tolerance: float, min_step: float) -> list[Setting]:
    """The settings worth a rung, cheapest first (see the module); empty when none reaches `floor`."""
    good = [s for s in settings if s.f1 >= floor]
    if not good:
        return []
    best_f1 = max(s.f1 for s in good)
    knee = min((s for s in good if s.f1 >= best_f1 - knee_tolerance), key=lambda s: s.bytes_per_frame)
    front: list[Setting] = []  # the Pareto front up to the knee
    for s in sorted(good, key=lambda s: (s.bytes_per_frame, -s.f1)):
        if s.bytes_per_frame > knee.bytes_per_frame:
            break
        if not front or s.f1 > front[-1].f1:
            front.append(s)
    rungs = [front[0]]  # the cheapest above the floor, steps of at least `min_step`, and the knee on top
    for s in front[1:-1]:
        if s.bytes_per_frame >= rungs[-1].bytes_per_frame * min_step:
            rungs.append(s)
    if len(front) > 1:
        if len(rungs) > 1 and front[-1].bytes_per_frame < rungs[-1].bytes_per_frame * min_step:
            rungs.pop()  # the knee replaces a rung too close below it
        rungs.append(front[-1])
    return rungs


def _clamped(setting: Setting, source_long_side: int | None) -> Setting:
    if source_long_side is None or setting.long_side is None or setting.long_side < source_long_side:
        return setting
    return replace(setting, long_side=None)


def _rung(setting: Setting) -> Rung:
    return Rung(
        setting.long_side, setting.quality, setting.f1, setting.bytes_per_frame, setting.codec, setting.bitrate_kbps
    )
