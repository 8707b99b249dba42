"""A recording as a frame source: a ROS 2 bag (a folder, MCAP or sqlite3 storage), an `.mcap` file or a ROS 1
`.bag`; the frames of one image topic with their header stamps, at the recorded rate times `rate`.

A message that is no usable frame (an unknown encoding, an oversized or short image) is skipped and counted by
reason; a bag that ends early (truncated, corrupt) ends the replay and is counted; one that cannot be opened, has no
such image topic or no frame that could be played is one line (`SourceError`).
"""

from __future__ import annotations

import collections
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from netapp.client.frames import SourceFrame
from netapp.client.sources import SourceError
from netapp.ros import require
from netapp.ros.images import ImageRefused, to_frame
from netapp.ros.messages import COMPRESSED_IMAGE, IMAGE

RECORDING_SUFFIXES = {".mcap", ".bag", ".db3"}
IMAGE_TYPES = {IMAGE, COMPRESSED_IMAGE, "sensor_msgs/Image", "sensor_msgs/CompressedImage"}
MAX_MESSAGE_BYTES = 64 * 1024 * 1024  # bounded before decoding: 4K RGB is 25 MB


def is_recording(path: str) -> bool:
    """A bag folder (with metadata.yaml), an `.mcap`, `.bag` or `.db3` file."""
    p = Path(path)
    return (p.is_dir() and (p / "metadata.yaml").is_file()) or p.suffix.lower() in RECORDING_SUFFIXES


class BagSource:
    """The frames of one image topic of a recording (iterate once). `skipped` counts what was left out, by reason.

    `topic` None: the first image topic. `rate`: 1.0 the recorded rate, 2.0 twice as fast; 0 gives no timeline
    (`offset_s` None), for a replay as fast as the netapp answers. `size` (width, height) resizes every frame.
    """

    def __init__(
        self,
        path: str,
        topic: str | None = None,
        rate: float = 1.0,
        size: tuple[int, int] | None = None,
        max_message_bytes: int = MAX_MESSAGE_BYTES,
    ) -> None:
        highlevel = require("rosbags.highlevel", SourceError, f"reading the recording {path}")
        if not Path(path).exists():
            raise SourceError(f"no such recording: {path}")
        if Path(path).suffix.lower() == ".db3":
            path = str(Path(path).parent)  # sqlite3 storage is read through its bag folder
        self.path, self.rate, self.size, self.max_message_bytes = path, rate, size, max_message_bytes
        self.skipped: collections.Counter[str] = collections.Counter()
        self.frames = 0
        try:
            self._reader = highlevel.AnyReader([Path(path)])
            self._reader.open()
        except Exception as exc:  # rosbags raises its own errors and lower ones (sqlite, zstd) for a bad file
            raise SourceError(f"cannot read the recording {path}: {_one_line(exc)}") from None
        images = {c.topic: c.msgtype for c in self._reader.connections if c.msgtype in IMAGE_TYPES}
        if not images:
            topics = sorted({c.topic for c in self._reader.connections})
            self._reader.close()
            raise SourceError(f"{path} has no image topic (its topics: {', '.join(topics) or 'none'})")
        if topic is None:
            topic = next(iter(images))
        elif topic not in images:
            self._reader.close()
            raise SourceError(f"{topic} is not an image topic of {path}; its image topics: {', '.join(images)}")
        self.topic = topic
        self._open = True
        self._connections = [c for c in self._reader.connections if c.topic == topic]

    def __iter__(self) -> Iterator[SourceFrame]:
        first: int | None = None
        try:
            for connection, log_time, raw in self._messages():
                if len(raw) > self.max_message_bytes:  # bounded before decoding
                    self.skipped["oversized"] += 1
                    continue
                first = log_time if first is None else first
                offset = (log_time - first) / 1e9 / self.rate if self.rate > 0 else None
                try:
                    message = self._reader.deserialize(raw, connection.msgtype)
                    frame = to_frame(connection.msgtype, message, offset).resized(self.size)
                except ImageRefused as exc:
                    self.skipped[str(exc)] += 1
                    continue
                except Exception:  # a message whose bytes do not decode as its type
                    self.skipped["undecodable message"] += 1
                    continue
                self.frames += 1
                yield frame
        finally:
            self.close()
        if not self.frames and self.skipped:
            reasons = "; ".join(f"{reason} (x{n})" for reason, n in self.skipped.items())
            raise SourceError(f"no frame of {self.topic} in {self.path} could be played: {reasons}")

    def _messages(self) -> Iterator[tuple[Any, int, bytes]]:
        """The topic's messages; a bag that ends early or breaks midway ends them, counted as `truncated`."""
        try:
            yield from self._reader.messages(connections=self._connections)
        except Exception:
            self.skipped["truncated or corrupt recording"] += 1

    def close(self) -> None:
        """Close the recording (iterating to the end closes it too); once."""
        if self._open:
            self._open = False
            self._reader.close()

    def report(self) -> dict[str, Any]:
        """What was replayed: the topic, the frames, and what was skipped by reason (for the summary)."""
        return {"topic": self.topic, "frames": self.frames, "skipped": dict(self.skipped)}


def read_bag(path: str, topic: str | None = None, rate: float = 0.0) -> Iterator[SourceFrame]:
    """The frames of a recording's image topic with their header stamps (`frame.stamp_ns`), for robot code:
    `for frame in read_bag("run.mcap"): client.send(frame.wire())`. rate 0: no timeline (read as fast as wanted)."""
    return iter(BagSource(path, topic, rate))


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
