"""A video as a ROS 2 bag (MCAP storage) of JPEG `CompressedImage`s: something to replay where no recording is at
hand (the docs' examples, `python -m bench.ros_replay`)."""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import cv2

from netapp.client.errors import OutputError
from netapp.client.sources import open_source
from netapp.ros import require
from netapp.ros.messages import COMPRESSED_IMAGE, header, typestore


def video_to_bag(
    video: str,
    bag: str | Path,
    frames: int,
    fps: float = 10.0,
    size: tuple[int, int] | None = None,
    topic: str = "/camera/image/compressed",
    jpeg_quality: int = 85,
) -> list[int]:
    """Write `frames` frames of `video` (resampled to `fps`, resized to `size`) to a new bag folder `bag`, stamped
    from now at `fps` (header stamp and log time alike); the stamps."""
    rosbag2 = require("rosbags.rosbag2", OutputError, "writing a bag")
    store = typestore()
    start_ns = time.time_ns()
    stamps = []
    writer = rosbag2.Writer(Path(bag), version=9, storage_plugin=rosbag2.StoragePlugin.MCAP)
    with writer:
        connection = writer.add_connection(topic, COMPRESSED_IMAGE, typestore=store)
        for i, frame in enumerate(itertools.islice(open_source(video, fps, size), frames)):
            stamp_ns = start_ns + round(i * 1e9 / fps)
            data = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])[1].ravel()
            message = store.types[COMPRESSED_IMAGE](header=header(store, stamp_ns, "camera"), format="jpeg", data=data)
            writer.write(connection, stamp_ns, store.serialize_cdr(message, COMPRESSED_IMAGE))
            stamps.append(stamp_ns)
    return stamps
