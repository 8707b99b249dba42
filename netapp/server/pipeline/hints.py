"""What the netapp tells robots of what it would like: its processor's input size, in the session info (the
`/register` answer, the Socket.IO `session_info` event before INIT's ack) and the model metadata, and the `hint` of
every result message (pure; docs/server.md#hints)."""

from __future__ import annotations

import math
from typing import Any

from netapp.protocol import ACCURACY_PROFILE_FIELD, INPUT_SIZE_FIELD, NEXT_FRAME_FIELD
from netapp.sdk.processor import Processor


def advertised_size(processor: Processor) -> list[int] | None:
    """The processor's declared `input_size` as [width, height], or None (any size, or not two positive ints)."""
    size = getattr(processor, "input_size", None)
    if (
        isinstance(size, (tuple, list))
        and len(size) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)
    ):
        return [int(size[0]), int(size[1])]
    return None


def session_info(processor: Processor) -> dict[str, Any]:
    """What a robot learns as its session opens."""
    profile = getattr(processor, "accuracy_profile", None)
    return {
        INPUT_SIZE_FIELD: advertised_size(processor),
        ACCURACY_PROFILE_FIELD: profile if isinstance(profile, str) else None,
    }


def metadata(processor: Processor) -> dict[str, Any]:
    """The processor's model metadata (`describe()`), with what robots should send it."""
    return {**processor.describe(), **session_info(processor)}


def result_hint(input_size: list[int] | None, next_frame_in_ms: float | None = None) -> dict[str, Any] | None:
    """The `hint` of a result message: the processor's size and, where the scheduler knows it, when the netapp will
    take the robot's next frame (ms from now). None when there is nothing to say."""
    hint: dict[str, Any] = {}
    if input_size is not None:
        hint[INPUT_SIZE_FIELD] = input_size
    if next_frame_in_ms is not None and math.isfinite(next_frame_in_ms):
        hint[NEXT_FRAME_FIELD] = round(max(0.0, next_frame_in_ms), 1)
    return hint or None
