"""A frame from a source with its stamp: the header stamp of a recorded image, or the capture time of a video frame.

A recording's compressed image keeps its bytes as recorded (`encoded`, `format`), so a JPEG goes to the netapp and
into an MCAP as it is, and is decoded only when something draws on it (`bgr()`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class SourceFrame:
    stamp_ns: int  # the image's header stamp (a recording) or its capture time (a video, an image, a camera)
    image: np.ndarray | None = None  # BGR; None until `bgr()` decodes `encoded`
    encoded: bytes | None = None  # the compressed bytes as recorded
    format: str = ""  # "jpeg" or "png" for `encoded`
    offset_s: float | None = None  # when to send it after the first frame (a recording's timeline); None: at --fps
    frame_id: str = ""  # the image's coordinate frame (ROS header.frame_id)
    index: int | None = None  # its place in the stream being sent, from 0 (set by `netapp.apps.streaming.stream`)

    @classmethod
    def captured(cls, image: np.ndarray) -> SourceFrame:
        """A frame captured now (a video, an image, a camera): stamped with the wall-clock time."""
        return cls(stamp_ns=time.time_ns(), image=image)

    def bgr(self) -> np.ndarray:
        """The frame as a BGR array (decoded from `encoded` once, when first asked)."""
        if self.image is None:
            decoded = cv2.imdecode(np.frombuffer(self.encoded or b"", np.uint8), cv2.IMREAD_COLOR)
            if decoded is None:
                raise ValueError(f"cannot decode the {self.format or 'compressed'} image")
            self.image = decoded
        return self.image

    def wire(self, as_recorded: bool = False) -> np.ndarray | bytes:
        """What to send: JPEG bytes as recorded (the netapp decodes them) when `as_recorded`, else the BGR array,
        which the client fits to the netapp's input size and encodes (a robot that is not sending full frames)."""
        if as_recorded and self.format == "jpeg" and self.encoded is not None:
            return self.encoded
        return self.bgr()

    def resized(self, size: tuple[int, int] | None) -> SourceFrame:
        """The frame at `size` (width, height): decoded and resized, its recorded bytes let go (they are another
        size); itself when it has that size already or no size is asked for."""
        if not size:
            return self
        image = self.bgr()
        if image.shape[1::-1] == tuple(size):
            return self
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        return SourceFrame(self.stamp_ns, image, offset_s=self.offset_s, frame_id=self.frame_id)
