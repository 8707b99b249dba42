"""What a frame decoder is: one per connection and frame event (`netapp.server.sio.handlers` keeps them)."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any, Protocol

import numpy as np


class FrameDecoder(Protocol):
    """How one connection's frames of one event become images. Stateful for video (H.264 references earlier
    pictures), so each connection gets its own, and its transport resets it (RESET_STATE) and closes it."""

    def frame(self, message: dict[str, Any]) -> Callable[[], np.ndarray] | Awaitable[np.ndarray]:
        """A validated frame message -> the decoding for the pipeline to run, or (video, decoded in order on
        the stream's own runner) the picture to await; FrameRejected if it cannot be."""
        ...

    def reset(self) -> None: ...

    def close(self) -> None: ...
