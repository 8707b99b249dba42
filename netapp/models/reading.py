"""Reading a model file: the onnxruntime session, and the signature the families recognise it by (tensors, shapes
probed once when symbolic, metadata, the user's overrides)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from netapp.models.card import ModelCard, ModelRefused, Tensor
from netapp.models.families import recognise
from netapp.models.families.base import Family, Signature
from netapp.models.labels import load_labels
from netapp.models.metadata import TASKS, read_metadata

DEFAULT_INPUT = 640  # the side of a model whose input size is symbolic and whose metadata names none
MAX_INPUT_PIXELS = 4096 * 2304  # an input's pixels at most unless told (`--max-pixels`'s default, as the netapp's)

_DTYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16, "tensor(int64)": np.int64}


def open_session(path: str, providers: list[Any] | None = None, options: Any = None) -> Any:
    """An onnxruntime session; ModelRefused, one line, for a file it cannot read (missing, truncated, not ONNX)."""
    import onnxruntime as ort

    if not Path(path).is_file():
        raise ModelRefused(f"model file {path} does not exist: give --model an ONNX file")
    try:
        return ort.InferenceSession(path, sess_options=options, providers=providers or ["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types for unreadable models
        with open(path, "rb") as file:
            other = other_format(file.read(HEAD_BYTES))
        if other:
            raise ModelRefused(f"{path} is not an ONNX model: {other}") from exc
        reason = " ".join(str(exc).split())[:300]
        raise ModelRefused(
            f"cannot load ONNX model {path} ({reason}): is the file complete? re-copy or re-export it"
        ) from exc


HEAD_BYTES = 512
# How other files begin (their magic numbers), and what to do instead
_MAGIC = (
    (b"PK\x03\x04", "it is a ZIP archive (a PyTorch .pt, or an archive of the model): export the model to ONNX"),
    (b"\x1f\x8b", "it is gzip-compressed: decompress it first"),
    (b"\x89HDF", "it is an HDF5 file (a Keras .h5): export the model to ONNX"),
    (b"\x80", "it is a Python pickle (a PyTorch checkpoint?): export the model to ONNX"),
)


def other_format(head: bytes) -> str | None:
    """What a file that onnxruntime cannot read is instead, from its first bytes (pure): text (an HTML error page
    saved as the model, a Git LFS pointer), an archive, a checkpoint; None when it may be an ONNX file cut short."""
    for magic, what in _MAGIC:
        if head.startswith(magic):
            return what
    if head[4:8] == b"TFL3":
        return "it is a TensorFlow Lite model: export the model to ONNX"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        text = head[:-4].decode("utf-8", "replace") if len(head) == HEAD_BYTES else ""  # cut inside a character
    if head and text and "\x00" not in text and sum(c.isprintable() or c.isspace() for c in text) >= 0.95 * len(text):
        first = " ".join(text.split())[:60]
        hint = " (a Git LFS pointer: git lfs pull)" if text.startswith("version https://git-lfs") else ""
        return f"it is text, beginning {first!r}{hint}: give --model the .onnx file itself"
    return None


def _tensor(arg: Any) -> Tensor:
    shape = tuple(d if isinstance(d, int) else str(d) for d in arg.shape)
    dtype = str(arg.type).removeprefix("tensor(").removesuffix(")")
    return Tensor(arg.name, shape, {"float": "float32", "double": "float64"}.get(dtype, dtype))


def bounded_hw(input_hw: tuple[int, int], max_pixels: int | None) -> tuple[int, int]:
    """`input_hw` itself when within `max_pixels` (`--max-pixels`); ModelRefused, one line, when not: every frame
    would be fed at it (a dynamic model whose metadata says `imgsz: [20000, 20000]` took 6.7 GB a frame)."""
    h, w = input_hw
    if max_pixels is not None and h * w > max_pixels:
        raise ModelRefused(
            f"the model's input of {w}x{h} is over --max-pixels {max_pixels}: re-export it at a smaller imgsz"
        )
    return input_hw


def _input_hw(inputs: tuple[Tensor, ...], imgsz: tuple[int, int] | None, fallback: int) -> tuple[int, int]:
    image = next((t for t in inputs if len(t.shape) == 4), None)
    if image is None:
        raise ModelRefused(
            f"inputs {', '.join(f'{t.name} {list(t.shape)}' for t in inputs)}: no image input (N, 3, H, W): "
            "this netapp serves image models only"
        )
    h, w = image.shape[2], image.shape[3]
    if isinstance(h, int) and isinstance(w, int):
        return h, w
    return imgsz or (fallback, fallback)


def probe_feeds(session: Any, input_hw: tuple[int, int]) -> dict[str, np.ndarray]:
    """Zeros for every input (the image at `input_hw`, a target size at the same), to learn symbolic output shapes."""
    feeds = {}
    for arg in session.get_inputs():
        dtype = _DTYPES.get(arg.type, np.float32)
        if len(arg.shape) == 4:
            feeds[arg.name] = np.zeros((1, 3, *input_hw), dtype)
        else:
            feeds[arg.name] = np.array([[input_hw[1], input_hw[0]]], dtype)
    return feeds


def signature(
    session: Any,
    *,
    task: str | None = None,
    labels: str | None = None,
    input_size: int = DEFAULT_INPUT,
    max_pixels: int | None = MAX_INPUT_PIXELS,
) -> Signature:
    """What the families recognise a model by; ModelRefused for a --task or --labels that cannot be used, or an
    input over `max_pixels`."""
    if task is not None and task not in TASKS:
        raise ModelRefused(f"--task {task} is not a task: give one of {', '.join(TASKS)}")
    metadata = read_metadata(session.get_modelmeta().custom_metadata_map)
    inputs = tuple(_tensor(a) for a in session.get_inputs())
    outputs = tuple(_tensor(a) for a in session.get_outputs())
    input_hw = bounded_hw(_input_hw(inputs, metadata.imgsz, input_size), max_pixels)
    if not all(isinstance(d, int) for t in outputs for d in t.shape[1:]):
        try:
            probed = session.run(None, probe_feeds(session, input_hw))
        except Exception as exc:  # the model cannot run on its own input size
            reason = " ".join(str(exc).split())[:200]
            raise ModelRefused(f"the model did not run on a {input_hw[1]}x{input_hw[0]} input ({reason})") from exc
        outputs = tuple(
            Tensor(t.name, (t.shape[0], *p.shape[1:]), t.dtype) for t, p in zip(outputs, probed, strict=True)
        )
    names = None
    if labels:
        try:
            names = tuple(load_labels(labels))
        except OSError as exc:
            raise ModelRefused(f"cannot read --labels {labels}: {exc.strerror}") from exc
    return Signature(
        inputs,
        outputs,
        metadata,
        input_hw,
        task=task,
        names=names or metadata.names,
        names_from="--labels" if names else "metadata",
    )


def read_model(
    path: str,
    *,
    task: str | None = None,
    layout: str | None = None,
    labels: str | None = None,
    session: Any = None,
    max_pixels: int | None = MAX_INPUT_PIXELS,
) -> tuple[Family, ModelCard]:
    """The family and card of a model file (a CPU session is opened when none is given)."""
    session = session or open_session(path)
    return recognise(signature(session, task=task, labels=labels, max_pixels=max_pixels), layout)
