"""What a family is: how it recognises an export (metadata first, then output shapes) and how it reads one frame's
outputs into candidates. A family is one file in this folder, registered in `families/__init__.py`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from netapp.models.card import ModelCard, ModelRefused, Pixels, Tensor
from netapp.models.metadata import Metadata
from netapp.models.preprocess import Placement
from netapp.models.tasks import Candidates


@dataclass(frozen=True)
class Signature:
    """What can be read from a model without running it on a frame: its tensors (output shapes probed once when
    symbolic), its metadata, and the user's overrides."""

    inputs: tuple[Tensor, ...]
    outputs: tuple[Tensor, ...]
    metadata: Metadata
    input_hw: tuple[int, int]  # the image input's (height, width)
    task: str | None = None  # --task
    names: tuple[str, ...] | None = None  # --labels, else the metadata's
    names_from: str = "metadata"  # or "--labels"

    @property
    def shapes(self) -> list[tuple[int | str, ...]]:
        return [t.shape for t in self.outputs]

    def output(self, name: str) -> Tensor | None:
        return next((t for t in self.outputs if t.name == name), None)

    def seen(self) -> str:
        """The outputs as the error lines quote them."""
        return ", ".join(f"{t.name} {list(t.shape)}" for t in self.outputs)


@dataclass(frozen=True)
class Recognition:
    """A family's claim on a model: the task, the classes it counts, the preprocessing, and why."""

    task: str
    num_classes: int
    pixels: Pixels
    why: str
    keypoints: tuple[int, int] | None = None
    mask_channels: int = 0
    default_names: Sequence[str] | None = None  # names when neither --labels nor the metadata give any
    extras: dict[str, Any] = field(default_factory=dict)


class Family:
    """One exporter's output format. Subclasses set `name` and `shapes` and implement `recognise` and
    `candidates`; both are pure."""

    name = ""
    shapes = ""  # the outputs it reads, for the error that lists the known families

    def recognise(self, sig: Signature) -> Recognition | None:
        """This family's reading of the model, None when the model is not one of its exports; ModelRefused when it
        is, but its metadata and outputs contradict each other."""
        raise NotImplementedError

    def candidates(self, outputs: Sequence[np.ndarray], card: ModelCard, conf: float) -> Candidates:
        """One frame's outputs (batch dimension removed) -> candidates over `conf`, in model-input pixels."""
        raise NotImplementedError

    def extra_inputs(self, card: ModelCard, placement: Placement) -> dict[str, np.ndarray]:
        """Inputs besides the image, for one frame (D-FINE's target size)."""
        return {}


def int_shape(shape: Sequence[int | str]) -> bool:
    return all(isinstance(d, int) for d in shape)


def contradiction(sig: Signature, what: str, expected: int) -> ModelRefused:
    """The metadata's class count does not fit the outputs: one line saying both, and what to do."""
    given = len(sig.names or ())
    said = "--labels gives" if sig.names_from == "--labels" else "the model's metadata names"
    return ModelRefused(
        f"{said} {given} classes but its outputs ({sig.seen()}) hold {expected} {what}: "
        "give --labels with one name per class, or re-export the model"
    )
