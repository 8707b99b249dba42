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
    # (width, height) the processor consumes, fitting each frame inside it with its aspect ratio kept (a letterbox);
    # None: any size. The netapp advertises it and robots send no larger frames (docs/sdk.md#input-size).
    input_size: tuple[int, int] | None = None
    # The accuracy profile its results follow as frames get smaller or coarser (a name in netapp/profiles,
    # made by `python -m bench.accuracy`); None: none is known, and adapting robots send frames as they are told.
    accuracy_profile: str | None = None

    def load(self) -> None:  # noqa: B027 (optional hook, not abstract)
        """Load weights and warm up; the netapp reports ready only after this returns."""

    def prepare(self, image: np.ndarray, args: Mapping[str, Any]) -> Any:
        """Per-frame work that can run beside inference (resize, normalise). `image` is BGR uint8 HxWx3."""
        return image

    @abstractmethod
    def process(self, batch: Sequence[Any]) -> list[dict[str, Any]]:
        """Results for a batch of prepared frames, in order."""

    def describe(self) -> dict[str, Any]:
        """Model metadata for `/v2/models/{name}` (the netapp adds `input_size`)."""
        return {"name": self.name, "platform": type(self).__name__}


class StatefulProcessor(Processor):
    """A processor that keeps state per robot session, e.g. a tracker.

    The model stays stateless and batched across robots (`process`); the state is a step after it: `update` gets
    each frame's result with its session's state, on the inference thread, in each session's frame order. The
    framework creates the state at INIT (or `/register`) with `new_state(args)`, drops it with the session, and
    moves it between netapps as JSON data (`state_to_json` / `state_from_json`): the 5G-ERA state commands
    (GET_STATE, SET_STATE, SAVE_STATE, LOAD_STATE, RESET_STATE) and the checkpoints a robot client keeps so that a
    new netapp continues where the old one stopped. Keep the state bounded: its JSON may not exceed
    `max_state_bytes`, and a larger one is refused with a clear message rather than sent or stored.
    """

    max_state_bytes: int = 256 * 1024

    @abstractmethod
    def new_state(self, args: Mapping[str, Any]) -> Any:
        """A fresh state for a session opened with INIT `args`."""

    @abstractmethod
    def update(self, state: Any, result: dict[str, Any], timestamp: int) -> dict[str, Any]:
        """The frame's final result, from `process`'s result and the session's state (which it may change in
        place). `timestamp` is the frame's, in nanoseconds of the robot's clock."""

    def state_to_json(self, state: Any) -> Any:
        """The state as JSON data (dicts, lists, strings, finite numbers); by default the state is that already."""
        return state

    def state_from_json(self, data: Any) -> Any:
        """A state from `state_to_json`'s output, which came over the network: raise ValueError saying what is
        wrong with it (the session then keeps its state)."""
        return data
