"""Recordings made here with rosbags (ROS 2 bags in MCAP or sqlite3 storage, ROS 1 bags of image messages), and
MCAP files read back with mcap-ros2-support."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

START_NS = 1_700_000_000_123_456_789  # header stamps start here (a stamp far from now, so none is confused with it)
PERIOD_NS = 50_000_000  # 20 FPS


def grey_frames(count: int, width: int = 160, height: int = 160) -> list[np.ndarray]:
    """Frames the tiny model finds its one box in (`tests/support/onnx_models.py`)."""
    return [np.full((height, width, 3), 90 + i % 3, np.uint8) for i in range(count)]


def image_message(store, image: np.ndarray, stamp_ns: int, encoding: str = "bgr8", compressed: str = ""):
    """A `sensor_msgs/msg/Image` in `encoding`, or a CompressedImage ("jpeg" or "png") of `image` (BGR)."""
    t = store.types
    stamp = t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    fields = {"stamp": stamp, "frame_id": "camera"}
    if "seq" in t["std_msgs/msg/Header"].__dataclass_fields__:  # ROS 1
        fields["seq"] = 0
    header = t["std_msgs/msg/Header"](**fields)
    if compressed:
        ok, buf = cv2.imencode(".jpg" if compressed == "jpeg" else ".png", image)
        assert ok
        return t["sensor_msgs/msg/CompressedImage"](header=header, format=compressed, data=buf.ravel())
    pixels = {
        "bgr8": image,
        "rgb8": image[:, :, ::-1],
        "mono8": cv2.cvtColor(image, cv2.COLOR_BGR2GRAY),
        "mono16": cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype("<u2") * 256,
    }.get(encoding, image)
    data = np.ascontiguousarray(pixels).view(np.uint8).ravel()
    height, width = image.shape[:2]
    return t["sensor_msgs/msg/Image"](
        header=header,
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=len(data) // height,
        data=data,
    )


def write_bag(
    path: Path,
    frames: list[np.ndarray],
    storage: str = "mcap",
    topic: str = "/camera/image",
    encoding: str = "bgr8",
    compressed: str = "",
    other_topics: tuple[str, ...] = (),
) -> list[int]:
    """A bag of `frames` on `topic` (storage "mcap", "sqlite3" or "ros1"), stamped START_NS + i * PERIOD_NS (header
    and log time alike), and a `std_msgs/msg/String` per frame on each of `other_topics`; the stamps."""
    from rosbags.typesys import Stores, get_typestore

    msgtype = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    stamps = [START_NS + i * PERIOD_NS for i in range(len(frames))]
    if storage == "ros1":
        from rosbags.rosbag1 import Writer as Ros1Writer

        store = get_typestore(Stores.ROS1_NOETIC)
        writer, serialize = Ros1Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        store = get_typestore(Stores.ROS2_HUMBLE)
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
    with writer:
        others = [writer.add_connection(t, "std_msgs/msg/String", typestore=store) for t in other_topics]
        images = writer.add_connection(topic, msgtype, typestore=store)
        for image, stamp in zip(frames, stamps, strict=True):
            for connection in others:
                text = store.types["std_msgs/msg/String"](data="hello")
                writer.write(connection, stamp, serialize(text, "std_msgs/msg/String"))
            message = image_message(store, image, stamp, encoding, compressed)
            writer.write(images, stamp, serialize(message, msgtype))
    return stamps


def read_mcap(path: Path) -> dict[str, list]:
    """Every message by topic: (log_time, message decoded by mcap-ros2-support with the definitions in the file)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    topics: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            topics.setdefault(channel.topic, []).append((message.log_time, decoded))
    return topics


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec
