"""The ROS 2 message types the toolkit reads and writes: the standard ones from rosbags' Humble typestore, plus
`vision_msgs` (4.x, as in ROS 2 Humble), which that typestore lacks, registered from its definitions' text."""

from __future__ import annotations

import functools
from typing import Any

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
DETECTION_ARRAY = "vision_msgs/msg/Detection2DArray"
IMAGE_ANNOTATIONS = "foxglove_msgs/msg/ImageAnnotations"
LATENCY = "netapp_msgs/msg/Latency"

# vision_msgs 4.x (ROS 2 Humble): https://github.com/ros-perception/vision_msgs/tree/ros2/vision_msgs/msg
VISION_MSGS = {
    "vision_msgs/msg/Point2D": "float64 x\nfloat64 y\n",
    "vision_msgs/msg/Pose2D": "vision_msgs/Point2D position\nfloat64 theta\n",
    "vision_msgs/msg/BoundingBox2D": "vision_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n",
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": (
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n"
    ),
    "vision_msgs/msg/Detection2D": (
        "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\nvision_msgs/BoundingBox2D bbox\n"
        "string id\n"
    ),
    "vision_msgs/msg/Detection2DArray": "std_msgs/Header header\nvision_msgs/Detection2D[] detections\n",
}

# foxglove_msgs (ROS 2, https://github.com/foxglove/schemas/tree/main/ros_foxglove_msgs/ros2/msg): Foxglove's Image
# panel lays ImageAnnotations over an image of the same stamp.
FOXGLOVE_MSGS = {
    "foxglove_msgs/msg/Color": "float64 r\nfloat64 g\nfloat64 b\nfloat64 a\n",
    "foxglove_msgs/msg/Point2": "float64 x\nfloat64 y\n",
    "foxglove_msgs/msg/CircleAnnotation": (
        "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nfloat64 diameter\nfloat64 thickness\n"
        "foxglove_msgs/Color fill_color\nfoxglove_msgs/Color outline_color\n"
    ),
    "foxglove_msgs/msg/PointsAnnotation": (
        "uint8 UNKNOWN=0\nuint8 POINTS=1\nuint8 LINE_LOOP=2\nuint8 LINE_STRIP=3\nuint8 LINE_LIST=4\n"
        "builtin_interfaces/Time timestamp\nuint8 type\nfoxglove_msgs/Point2[] points\n"
        "foxglove_msgs/Color outline_color\nfoxglove_msgs/Color[] outline_colors\nfoxglove_msgs/Color fill_color\n"
        "float64 thickness\n"
    ),
    "foxglove_msgs/msg/TextAnnotation": (
        "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nstring text\nfloat64 font_size\n"
        "foxglove_msgs/Color text_color\nfoxglove_msgs/Color background_color\n"
    ),
    "foxglove_msgs/msg/ImageAnnotations": (
        "foxglove_msgs/CircleAnnotation[] circles\nfoxglove_msgs/PointsAnnotation[] points\n"
        "foxglove_msgs/TextAnnotation[] texts\n"
    ),
}

# The toolkit's own: a result's latency and its parts (0 where the netapp did not stamp them), for a Plot panel.
NETAPP_MSGS = {
    LATENCY: (
        "std_msgs/Header header\nfloat64 latency_ms\nfloat64 uplink_ms\nfloat64 queue_ms\nfloat64 inference_ms\n"
        "float64 downlink_ms\nstring source\nbool late\n"
    ),
}


@functools.cache
def typestore() -> Any:
    """rosbags' ROS 2 Humble typestore with `vision_msgs`, `foxglove_msgs` and `netapp_msgs` registered (needs the
    `ros` extra)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in {**VISION_MSGS, **FOXGLOVE_MSGS, **NETAPP_MSGS}.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def stamp(store: Any, stamp_ns: int) -> Any:
    """A `builtin_interfaces/msg/Time` for `stamp_ns`."""
    return store.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)


def header(store: Any, stamp_ns: int, frame_id: str) -> Any:
    return store.types["std_msgs/msg/Header"](stamp=stamp(store, stamp_ns), frame_id=frame_id)
