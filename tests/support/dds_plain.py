"""`sensor_msgs/msg/Image` as cyclonedds reads it without help (`data` a list of ints): what a ROS 2 peer's type
looks like, to compare netapp/ros/dds_types.py's against. No `from __future__ import annotations`: cyclonedds
reads the annotations as types."""

from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import sequence, uint8, uint32

from netapp.ros.dds_types import Header_


@dataclass
class PlainImage_(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header_ = field(default_factory=Header_)
    height: uint32 = 0
    width: uint32 = 0
    encoding: str = ""
    is_bigendian: uint8 = 0
    step: uint32 = 0
    data: sequence[uint8] = field(default_factory=list)
