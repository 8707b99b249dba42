"""`sensor_msgs/msg/Image` as cyclonedds reads it without help (`data` a list of ints): what a ROS 2 peer's type
looks like, to compare netapp/ros/dds_types.py's against; the same fields, from `Image_` itself."""

from __future__ import annotations

import types
from dataclasses import dataclass

from cyclonedds.idl import IdlStruct

from netapp.ros.dds_types import Image_

PlainImage_ = dataclass(
    types.new_class(
        "PlainImage_",
        (IdlStruct,),
        {"typename": "sensor_msgs::msg::dds_::Image_"},
        lambda namespace: namespace.update(__annotations__=dict(Image_.__annotations__)),
    )
)
