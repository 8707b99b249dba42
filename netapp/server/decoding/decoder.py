"""What a frame decoder is: one per connection and codec (each transport's `Connection` keeps its own)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from netapp.frame import EncodedFrame


class FrameDecoder(Protocol):
    """How one connection's frames of one event become images. Stateful for video (H.264 references earlier
    pictures), so each connection gets its own, and its transport resets it (RESET_STATE) and closes it.
    `in_order`: its decodings must run in the order of the frames (video: each needs the ones before it), so the
    pipeline runs them on the frame's lane, never on the prepare pool."""

    in_order: bool

    def frame(self, frame: EncodedFrame) -> Callable[[], np.ndarray]:
        """A frame its transport's edge checked -> the decoding for the pipeline to run; FrameRejected if it cannot
        be."""
        ...

    def reset(self) -> None: ...

    def close(self) -> None: ...
