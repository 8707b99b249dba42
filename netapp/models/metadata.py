"""What an ONNX export says about itself: Ultralytics writes `task`, `names`, `imgsz`, `stride`, `kpt_shape`, `end2end`
and `head` into the model's metadata as Python reprs (`{0: 'person'}`, `[640, 640]`, `'True'`). Pure."""

from __future__ import annotations

import ast
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from netapp.models.card import ModelRefused
from netapp.models.labels import names_from_metadata

# The keys read here are parsed as Python literals, and a literal's parse costs about 100 times its text (a 1 MB
# `names` took 120 MB, a 54 MB one 1.9 GB): each is bounded before it is parsed.
MAX_METADATA_CHARS = 512 * 1024  # a value the model layer parses; ImageNet-21k's names as Ultralytics writes them fit
MAX_NAMES = 100_000
PARSED_KEYS = ("task", "names", "labels", "classes", "imgsz", "stride", "kpt_shape", "end2end", "head")

TASKS = ("detect", "segment", "pose", "obb", "classify")
# Ultralytics' own spellings of the tasks, in older exports' metadata and in users' habits
TASK_ALIASES = {"detection": "detect", "segmentation": "segment", "seg": "segment", "classification": "classify"}


def literal(raw: str | None) -> Any:
    """A metadata value: a Python literal, else JSON, else the string itself (None stays None)."""
    if raw is None:
        return None
    for parse in (ast.literal_eval, json.loads):
        try:
            return parse(raw)
        except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
            continue
    return raw


def task_name(raw: Any) -> str | None:
    """A task as this package names it (detect, segment, pose, obb, classify), or None when it names none of them."""
    if not isinstance(raw, str):
        return None
    name = TASK_ALIASES.get(raw.strip().lower(), raw.strip().lower())
    return name if name in TASKS else None


@dataclass(frozen=True)
class Metadata:
    """The metadata fields the model layer reads; `raw` keeps every key as written."""

    task: str | None = None
    names: tuple[str, ...] | None = None
    imgsz: tuple[int, int] | None = None  # (height, width)
    stride: int | None = None
    kpt_shape: tuple[int, int] | None = None  # (keypoints, values per keypoint: 2 or 3)
    end2end: bool | None = None
    head: str | None = None
    raw: Mapping[str, str] = field(default_factory=dict)

    @property
    def ultralytics(self) -> bool:
        """Written by Ultralytics' exporter (it always writes `task` and `names`)."""
        return self.task is not None and self.names is not None


def _pair(value: Any) -> tuple[int, int] | None:
    if isinstance(value, int) and not isinstance(value, bool) and value > 0:
        return value, value
    if isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(v, int) and v > 0 for v in value):
        return int(value[0]), int(value[1])
    return None


def bounded(raw: Mapping[str, str]) -> Mapping[str, str]:
    """`raw` itself when every value the model layer parses is within `MAX_METADATA_CHARS`; ModelRefused, one line,
    before any is parsed, when one is not."""
    for key in PARSED_KEYS:
        value = raw.get(key)
        if value is not None and len(value) > MAX_METADATA_CHARS:
            raise ModelRefused(
                f"the model's metadata '{key}' is {len(value)} characters, over {MAX_METADATA_CHARS}: "
                "re-export the model with its metadata within bounds"
            )
    return raw


def read_metadata(raw: Mapping[str, str]) -> Metadata:
    """The fields of an ONNX model's custom metadata map; values it cannot read are left None. ModelRefused for
    a value too big to parse (`bounded`) or more than `MAX_NAMES` class names."""
    raw = bounded(raw)
    end2end = literal(raw.get("end2end"))
    stride = literal(raw.get("stride"))
    names = names_from_metadata(dict(raw))
    head = literal(raw.get("head"))
    if names and len(names) > MAX_NAMES:
        raise ModelRefused(f"the model's metadata names {len(names)} classes, over {MAX_NAMES}: re-export the model")
    return Metadata(
        task=task_name(raw.get("task")),
        names=tuple(names) if names else None,
        imgsz=_pair(literal(raw.get("imgsz"))),
        stride=stride if isinstance(stride, int) and not isinstance(stride, bool) else None,
        kpt_shape=_pair(literal(raw.get("kpt_shape"))),
        end2end=end2end if isinstance(end2end, bool) else None,
        head=head if isinstance(head, str) else None,
        raw=dict(raw),
    )
