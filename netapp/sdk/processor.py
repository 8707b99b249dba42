"""The contract between the netapp framework and an algorithm."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np


class Processor(ABC):
    """One shared instance serves every robot session.

    `prepare` runs per frame on a small thread pool (it may raise ValueError for input it cannot take: the sender
    gets that message); `process` runs on the single inference thread with up to `max_batch` prepared frames from
    different robots and returns one JSON-serialisable dict per frame, merged into that frame's result message.
    """

    name: str = "processor"
    max_batch: int = 1

    def load(self) -> None:  # noqa: B027 (optional hook, not abstract)
        """Load weights and warm up; the netapp reports ready only after this returns."""

    def prepare(self, image: np.ndarray, args: Mapping[str, Any]) -> Any:
        """Per-frame work that can run beside inference (resize, normalise). `image` is BGR uint8 HxWx3."""
        return image

    @abstractmethod
    def process(self, batch: Sequence[Any]) -> list[dict[str, Any]]:
        """Results for a batch of prepared frames, in order."""

    def describe(self) -> dict[str, Any]:
        """Model metadata for `/v2/models/{name}`."""
        return {"name": self.name, "platform": type(self).__name__}
