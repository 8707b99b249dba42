"""What rides along the inference path without being part of it: an `InferenceHook` (a model rollout is one,
`netapp.server.rollout.rollout.Rollout`, attached by `netapp.server.services`), so the pipeline imports nothing of it.

Beside the results' observers (`observers`), a hook sees the frames before inference and the batches after it: it
may keep a frame's decoded picture, answer a session's frames with a processor of its own, hear when that processor
fails a frame, and take each batch once its results have gone to their robots (so it never delays them)."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from netapp.sdk.processor import Processor
from netapp.server.pipeline.frame import Frame
from netapp.server.pipeline.scheduling import Batch
from netapp.server.sessions import Session


class InferenceHook(Protocol):
    def keep_image(self, frame: Frame, image: np.ndarray) -> None:
        """On the thread that decodes `frame`: its picture, for the hook to keep if it needs it."""
        ...

    def processor_for(self, session: Session) -> Processor | None:
        """The processor of the hook's own that answers this session's next frame; None: the pipeline's."""
        ...

    def processor_failed(self, error: str) -> None:
        """On an inference thread: the hook's processor (from `processor_for`) failed a frame; its robot got the
        error."""
        ...

    def after_batch(self, batch: Batch, outputs: list[Any], before_ns: int, after_ns: int) -> None:
        """On the event loop, once the batch's results have gone to their robots: its frames, their outputs, and
        when the model's call began and ended."""
        ...

    def stop(self) -> None:
        """The pipeline stops: end what the hook runs."""
        ...
