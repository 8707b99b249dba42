"""ROS 2 messages as DDS types, named as ROS 2's middlewares name them (`sensor_msgs::msg::dds_::Image_`), for the
live bridge over cyclonedds (the `ros` extra's `cyclonedds`). Fields and order as in ROS 2 Humble; vision_msgs 4.x.

A ROS 2 node on a DDS middleware (rmw_cyclonedds_cpp, rmw_fastrtps_cpp) should see these as its own messages on
topic `rt/<name>`; checked here only against cyclonedds itself (rclpy cannot be installed on these machines).
No `from __future__ import annotations`: cyclonedds reads the annotations as types.
"""

import types
from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl._machinery import BytesMachine, PlainCdrV2SequenceOfPrimitiveMachine
from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32


@dataclass
class Time_(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header_(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time_ = field(default_factory=Time_)
    frame_id: str = ""


@dataclass
class Image_(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header_ = field(default_factory=Header_)
    height: uint32 = 0
    width: uint32 = 0
    encoding: str = ""
    is_bigendian: uint8 = 0
    step: uint32 = 0
    data: sequence[uint8] = b""  # read and written as bytes (`read_as_bytes`)


@dataclass
class CompressedImage_(IdlStruct, typename="sensor_msgs::msg::dds_::CompressedImage_"):
    header: Header_ = field(default_factory=Header_)
    format: str = ""
    data: sequence[uint8] = b""  # read and written as bytes (`read_as_bytes`)


@dataclass
class Point_(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion_(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose_(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point_ = field(default_factory=Point_)
    orientation: Quaternion_ = field(default_factory=Quaternion_)


@dataclass
class PoseWithCovariance_(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose_ = field(default_factory=Pose_)
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class ObjectHypothesis_(IdlStruct, typename="vision_msgs::msg::dds_::ObjectHypothesis_"):
    class_id: str = ""
    score: float64 = 0.0


@dataclass
class ObjectHypothesisWithPose_(IdlStruct, typename="vision_msgs::msg::dds_::ObjectHypothesisWithPose_"):
    hypothesis: ObjectHypothesis_ = field(default_factory=ObjectHypothesis_)
    pose: PoseWithCovariance_ = field(default_factory=PoseWithCovariance_)


@dataclass
class Point2D_(IdlStruct, typename="vision_msgs::msg::dds_::Point2D_"):
    x: float64 = 0.0
    y: float64 = 0.0


@dataclass
class Pose2D_(IdlStruct, typename="vision_msgs::msg::dds_::Pose2D_"):
    position: Point2D_ = field(default_factory=Point2D_)
    theta: float64 = 0.0


@dataclass
class BoundingBox2D_(IdlStruct, typename="vision_msgs::msg::dds_::BoundingBox2D_"):
    center: Pose2D_ = field(default_factory=Pose2D_)
    size_x: float64 = 0.0
    size_y: float64 = 0.0


@dataclass
class Detection2D_(IdlStruct, typename="vision_msgs::msg::dds_::Detection2D_"):
    header: Header_ = field(default_factory=Header_)
    results: sequence[ObjectHypothesisWithPose_] = field(default_factory=list)
    bbox: BoundingBox2D_ = field(default_factory=BoundingBox2D_)
    id: str = ""


@dataclass
class Detection2DArray_(IdlStruct, typename="vision_msgs::msg::dds_::Detection2DArray_"):
    header: Header_ = field(default_factory=Header_)
    detections: sequence[Detection2D_] = field(default_factory=list)


# foxglove_msgs (ROS 2, as netapp/ros/messages.py defines them for rosbags): the bridge's image annotations.


@dataclass
class Color_(IdlStruct, typename="foxglove_msgs::msg::dds_::Color_"):
    r: float64 = 0.0
    g: float64 = 0.0
    b: float64 = 0.0
    a: float64 = 0.0


@dataclass
class Point2_(IdlStruct, typename="foxglove_msgs::msg::dds_::Point2_"):
    x: float64 = 0.0
    y: float64 = 0.0


@dataclass
class CircleAnnotation_(IdlStruct, typename="foxglove_msgs::msg::dds_::CircleAnnotation_"):
    timestamp: Time_ = field(default_factory=Time_)
    position: Point2_ = field(default_factory=Point2_)
    diameter: float64 = 0.0
    thickness: float64 = 0.0
    fill_color: Color_ = field(default_factory=Color_)
    outline_color: Color_ = field(default_factory=Color_)


@dataclass
class PointsAnnotation_(IdlStruct, typename="foxglove_msgs::msg::dds_::PointsAnnotation_"):
    timestamp: Time_ = field(default_factory=Time_)
    type: uint8 = 0
    points: sequence[Point2_] = field(default_factory=list)
    outline_color: Color_ = field(default_factory=Color_)
    outline_colors: sequence[Color_] = field(default_factory=list)
    fill_color: Color_ = field(default_factory=Color_)
    thickness: float64 = 0.0


@dataclass
class TextAnnotation_(IdlStruct, typename="foxglove_msgs::msg::dds_::TextAnnotation_"):
    timestamp: Time_ = field(default_factory=Time_)
    position: Point2_ = field(default_factory=Point2_)
    text: str = ""
    font_size: float64 = 0.0
    text_color: Color_ = field(default_factory=Color_)
    background_color: Color_ = field(default_factory=Color_)


@dataclass
class ImageAnnotations_(IdlStruct, typename="foxglove_msgs::msg::dds_::ImageAnnotations_"):
    circles: sequence[CircleAnnotation_] = field(default_factory=list)
    points: sequence[PointsAnnotation_] = field(default_factory=list)
    texts: sequence[TextAnnotation_] = field(default_factory=list)


def read_as_bytes(message: type, name: str = "data") -> bool:
    """Read and write the `sequence<uint8>` field `name` of `message` as bytes, not as a list of ints.

    cyclonedds's generic machine for a sequence of primitives packs and unpacks it element by element: a 1280x720
    BGR image costs about 130 ms to write and 40 ms to read into bytes (docs/ros.md#the-bridges-cost). On the wire a
    `sequence<uint8>` is what its bytes machine writes (a 4-byte aligned uint32 length, then the octets), so it takes
    its place; the type's XTypes description still says `sequence<uint8>`, so peers match as before. This reaches
    into cyclonedds's machines (checked against 11.0.1): where they differ, the type is left as it was (False)."""
    idl = message.__idl__
    idl.populate()
    machines = [getattr(m, "members_machines", None) for m in (idl.v1_machine, idl.v2_machine)]
    if not all(m is not None and isinstance(m.get(name), PlainCdrV2SequenceOfPrimitiveMachine) for m in machines):
        return False
    for members in machines:
        members[name] = BytesMachine()
    return True


def as_generic_reader_sees_it(message: type) -> type:
    """`message` under the same name, fields and XTypes type id, read as cyclonedds reads it without
    `read_as_bytes` (a `sequence<uint8>` as a list of ints): what the bridge did before, to compare and measure."""
    return dataclass(
        types.new_class(
            message.__name__,
            (IdlStruct,),
            {"typename": message.__idl_typename__},
            lambda namespace: namespace.update(__annotations__=dict(message.__annotations__)),
        )
    )


read_as_bytes(Image_)
read_as_bytes(CompressedImage_)
