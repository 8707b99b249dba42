"""Where `netapp stream` puts each result besides its summary: an annotated video, a JSON-lines file, a window.

Each sink takes (frame, result) as results arrive, on the streaming thread (never on the transport's thread, so
a slow disk never delays the next result), and is closed at the end.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any, Protocol

import cv2

from netapp.client.draw import draw_result
from netapp.client.errors import OutputError
from netapp.client.fallback import LOCAL
from netapp.client.frames import SourceFrame
from netapp.client.netapp_client import Result
from netapp.protocol import RESULT_FIELDS


class Sink(Protocol):
    needs_frames: bool

    def add(self, frame: SourceFrame | None, result: Result) -> None: ...

    def close(self) -> None: ...


def processor_output(message: dict[str, Any]) -> dict[str, Any]:
    """The fields of a result message that its processor added (what a custom processor returned); the local
    fallback's `source` mark is the client's, not the processor's."""
    return {k: v for k, v in message.items() if k not in RESULT_FIELDS and not (k == "source" and v == LOCAL)}


def result_record(result: Result) -> dict[str, Any]:
    """One JSON-lines record: the frame's timestamp, latency and its parts, detections, the processor's output."""
    record: dict[str, Any] = {
        "timestamp": result.timestamp,
        "latency_ms": round(result.latency_ms, 2),
        "breakdown_ms": result.breakdown.as_dict() if result.breakdown else None,
        "source": result.source,
        "late": result.late,
        "detections": result.detections,
    }
    if result.source_stamp_ns is not None:
        record["source_stamp_ns"] = result.source_stamp_ns
    if result.frame_index is not None:
        record["frame"] = result.frame_index
    if result.sent is not None:
        record["sent"] = result.sent
    output = processor_output(result.message)
    if output:
        record["output"] = output
    return record


class JsonLines:
    needs_frames = False

    def __init__(self, path: str) -> None:
        try:
            self._file = open(path, "w", encoding="utf-8")  # closed by close()
        except OSError as exc:
            raise OutputError(f"cannot write --jsonl {path}: {exc.strerror}") from None

    def add(self, frame: SourceFrame | None, result: Result) -> None:
        self._file.write(json.dumps(result_record(result), default=str) + "\n")

    def close(self) -> None:
        self._file.close()


class AnnotatedVideo:
    """One video frame per result: the frame that was sent, its boxes and latency drawn (mp4v, at `fps`)."""

    needs_frames = True

    def __init__(self, path: str, fps: float) -> None:
        parent = Path(path).resolve().parent
        if not parent.is_dir() or not os.access(parent, os.W_OK):
            raise OutputError(f"cannot write --save {path}: {parent} is not a writable folder")
        self.path, self.fps = path, fps
        self._writer: cv2.VideoWriter | None = None
        self._size: tuple[int, int] = (0, 0)
        self.frames = 0

    def add(self, source: SourceFrame | None, result: Result) -> None:
        if source is None:
            return
        frame = source.bgr()
        if self._writer is None:
            self._size = (frame.shape[1], frame.shape[0])
            self._writer = cv2.VideoWriter(self.path, cv2.VideoWriter_fourcc(*"mp4v"), self.fps, self._size)
            if not self._writer.isOpened():
                raise OutputError(f"cannot write --save {self.path}: OpenCV has no mp4v encoder here")
        elif frame.shape[1::-1] != self._size:
            frame = cv2.resize(frame, self._size)  # a camera that changed resolution: keep one video size
        self._writer.write(draw_result(frame, result))
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()


class Window:
    """An OpenCV window showing each frame with its result; needs a display and OpenCV built with a GUI."""

    needs_frames = True
    title = "netapp stream"

    def __init__(self) -> None:
        if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise OutputError("--show needs a display (DISPLAY is not set); use --save out.mp4 instead")
        try:
            cv2.namedWindow(self.title, cv2.WINDOW_NORMAL)
        except cv2.error:
            raise OutputError(
                "--show needs OpenCV with a GUI (this one is headless: pip install opencv-python); "
                "use --save out.mp4 instead"
            ) from None

    def add(self, frame: SourceFrame | None, result: Result) -> None:
        if frame is not None:
            cv2.imshow(self.title, draw_result(frame.bgr(), result))
            cv2.waitKey(1)

    def close(self) -> None:
        cv2.destroyWindow(self.title)
