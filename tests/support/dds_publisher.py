"""A ROS 2 camera stand-in for the bridge's tests, in its own process: `python -m tests.support.dds_publisher TOPIC
COUNT` publishes COUNT grey 160x160 bgr8 `sensor_msgs/msg/Image`s over DDS (sensor-data QoS) at 20 Hz, stamped
START_NS + i * PERIOD_NS (tests/support/bags.py), the way a ROS 2 camera node would."""

from __future__ import annotations

import sys
import time

from tests.support.bags import PERIOD_NS, START_NS


def main(topic: str, count: int) -> None:
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from netapp.ros.bridge import SENSOR_DATA_DEPTH, dds_topic
    from netapp.ros.dds_types import Header_, Image_, Time_

    participant = DomainParticipant(0)
    qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(SENSOR_DATA_DEPTH), Policy.Durability.Volatile)
    writer = DataWriter(participant, Topic(participant, dds_topic(topic), Image_), qos=qos)
    pixels = bytes([90]) * (160 * 160 * 3)
    for i in range(count):
        stamp = START_NS + i * PERIOD_NS
        header = Header_(Time_(stamp // 10**9, stamp % 10**9), "camera")
        writer.write(Image_(header, 160, 160, "bgr8", 0, 480, pixels))
        time.sleep(PERIOD_NS / 1e9)  # a camera's frame rate


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))
