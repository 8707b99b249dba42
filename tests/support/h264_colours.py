"""H.264 streams of solid colours from a palette, so that a decoded picture's mean colour tells which frame it was
(a packet decoded out of order or from a broken reference comes out in the wrong colour): shared by
tests/netapp/server/test_h264.py and test_h264_decoding.py."""

from __future__ import annotations

from typing import Any

import numpy as np

from netapp.client.h264 import encode_frame
from netapp.client.transports.socketio import era_message

PALETTE = [(0, 0, 255), (0, 255, 0), (255, 0, 0), (255, 255, 255), (40, 120, 200), (200, 40, 90), (0, 0, 0)]
WIDTH, HEIGHT = 128, 96
TOLERANCE = 12  # per channel, after yuv420p and lossy coding
DEADLINE_S = 30.0  # generous: two shared cores


def colour_frame(i: int, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    frame = np.empty((height, width, 3), np.uint8)
    frame[:] = PALETTE[i % len(PALETTE)]
    return frame


def assert_colour(message: dict[str, Any], i: int) -> None:
    got = np.array(message["colour"])
    assert np.abs(got - PALETTE[i % len(PALETTE)]).max() <= TOLERANCE, f"frame {i}: decoded {got}"


def stream_messages(
    count: int, options: dict[str, str] | None = None, width: int = WIDTH, height: int = HEIGHT
) -> list[dict[str, Any]]:
    """Encoded messages for frames 0..count-1 with timestamps 1..count."""
    encoder, messages = None, []
    for i in range(count):
        frame, encoder = encode_frame(encoder, colour_frame(i, width, height), i + 1, options)
        messages.append(era_message(frame))
    return messages
