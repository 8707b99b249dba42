"""A model's card: what the model layer recognised in an ONNX file, and why (`netapp model inspect` prints it)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


class ModelRefused(ValueError):
    """The model cannot be served; the message is one line saying what was seen and what to do."""


@dataclass(frozen=True)
class Tensor:
    """An input or output of the graph: its name, shape (symbolic dimensions as strings) and element type."""

    name: str
    shape: tuple[int | str, ...]
    dtype: str = "float32"


@dataclass(frozen=True)
class Pixels:
    """How a frame becomes the model's input."""

    size_hw: tuple[int, int]
    resize: (
        str  # "letterbox" (centred), "letterbox-corner" (YOLOX: top-left), "stretch", "crop" (shorter side + centre)
    )
    rgb: bool
    scale: float  # 1/255 or 1
    mean: tuple[float, ...] | None = None  # after scale, then / std (ImageNet for RF-DETR)
    std: tuple[float, ...] | None = None

    def describe(self) -> str:
        norm = f", mean {list(self.mean)} std {list(self.std)}" if self.mean and self.std else ""
        scale = "0-1" if self.scale != 1.0 else "0-255"
        return f"{self.size_hw[1]}x{self.size_hw[0]} {self.resize}, {'RGB' if self.rgb else 'BGR'} {scale}{norm}"


@dataclass(frozen=True)
class ModelCard:
    """Family, task, input, classes, outputs and keypoints of a model, and the one-line reason it was recognised."""

    family: str
    task: str
    pixels: Pixels
    classes: tuple[str, ...]
    inputs: tuple[Tensor, ...]
    outputs: tuple[Tensor, ...]
    why: str
    keypoints: tuple[int, int] | None = None  # (count, values per keypoint)
    keypoint_names: tuple[str, ...] | None = None
    skeleton: tuple[tuple[int, int], ...] | None = None
    mask_channels: int = 0  # segmentation: mask coefficients per detection
    extras: dict[str, Any] = field(default_factory=dict)  # a family's own facts (the YOLO anchor count, say)

    @property
    def num_classes(self) -> int:
        return len(self.classes)

    def line(self) -> str:
        """The one line `netapp serve` logs at start."""
        return f"{self.family} {self.task}, {self.num_classes} classes, input {self.pixels.describe()}: {self.why}"

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out.pop("extras")  # a family's working data (arrays), not facts for a reader
        out["classes"] = list(self.classes)
        out["num_classes"] = self.num_classes
        return out

    def text(self) -> str:
        """The card as a person reads it."""
        shown = ", ".join(self.classes[:10]) + (f", ... ({self.num_classes} in all)" if self.num_classes > 10 else "")
        rows = [
            ("family", self.family),
            ("task", self.task),
            ("why", self.why),
            ("input", self.pixels.describe()),
            ("inputs", "; ".join(f"{t.name} {list(t.shape)} {t.dtype}" for t in self.inputs)),
            ("outputs", "; ".join(f"{t.name} {list(t.shape)} {t.dtype}" for t in self.outputs)),
            ("classes", shown or "-"),
        ]
        if self.keypoints:
            rows.append(("keypoints", f"{self.keypoints[0]} x {self.keypoints[1]}"))
            if self.skeleton:
                rows.append(("skeleton", f"{len(self.skeleton)} limbs"))
        if self.mask_channels:
            rows.append(("masks", f"{self.mask_channels} coefficients x prototypes"))
        width = max(len(k) for k, _ in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)
