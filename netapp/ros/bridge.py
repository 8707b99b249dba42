"""`netapp ros2 URL --image-topic T`: a live bridge from a ROS 2 image topic to a netapp and back, over DDS
(cyclonedds, the `ros` extra) with ROS 2's naming (`rt/` topics, `sensor_msgs::msg::dds_::Image_` types) and the
sensor-data QoS (best effort, keep last 5, volatile) for images (`docs/ros.md#live-bridge`).

Each image goes to the netapp as it arrives (`NetAppClient.send` never waits: the newest frame wins, paced and
adaptive like any robot); each result goes out as `vision_msgs/msg/Detection2DArray` with the image's header, and as
`foxglove_msgs/msg/ImageAnnotations` stamped like the image on a sibling topic: what vision_msgs has no field for
(masks as filled polygons, keypoints as points with the skeleton's limbs, oriented boxes, an image classification's
classes), the same annotations `--mcap` records (netapp/ros/foxglove.py).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any

from netapp.client.delivery import Result
from netapp.client.errors import NetAppError
from netapp.client.netapp_client import NetAppClient
from netapp.detections import Detections
from netapp.results import CLASSIFICATIONS_FIELD
from netapp.ros import foxglove, require
from netapp.ros.detections import vision_detections
from netapp.ros.images import ImageRefused, to_frame
from netapp.ros.messages import IMAGE_ANNOTATIONS, typestore

SENSOR_DATA_DEPTH = 5  # rclcpp's SensorDataQoS: best effort, keep last 5, volatile
DETECTIONS_DEPTH = 10  # rclcpp's default QoS: reliable, keep last 10, volatile
PENDING = 64  # images awaiting their result (the client holds far fewer in flight)


def dds_topic(name: str) -> str:
    """ROS 2's DDS topic for a ROS topic name: `/camera/image` -> `rt/camera/image`."""
    return "rt/" + name.lstrip("/")


class ResultPublisher:
    """Publishes results on a DDS participant with ROS 2's names: `vision_msgs/Detection2DArray` on
    `detections_topic` (reliable, keep last 10) and `foxglove_msgs/ImageAnnotations` on `annotations_topic`, each
    with the header given (the bridge's: its image's; `netapp watch --ros2`'s: the camera's)."""

    def __init__(self, participant: Any, detections_topic: str, annotations_topic: str) -> None:
        from cyclonedds.core import Policy, Qos
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        from netapp.ros import dds_types

        self._store = typestore()  # builds the annotations as --mcap does; CDR is the same on DDS
        self._types = dds_types
        reliable = Qos(
            Policy.Reliability.Reliable(0), Policy.History.KeepLast(DETECTIONS_DEPTH), Policy.Durability.Volatile
        )
        self._writer = DataWriter(
            participant, Topic(participant, dds_topic(detections_topic), dds_types.Detection2DArray_), qos=reliable
        )
        self._annotations = DataWriter(
            participant, Topic(participant, dds_topic(annotations_topic), dds_types.ImageAnnotations_), qos=reliable
        )

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        """A std_msgs/Header stamped `stamp_ns` (ns since the epoch)."""
        t = self._types
        return t.Header_(t.Time_(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000), frame_id)

    def publish(self, result: Result, header: Any, size: tuple[int, int] | None) -> None:
        t = self._types
        detections = Detections.from_wire(result.detections, strict=False)
        items = [
            t.Detection2D_(
                header=header,
                results=[t.ObjectHypothesisWithPose_(hypothesis=t.ObjectHypothesis_(d.class_id, d.score))],
                bbox=t.BoundingBox2D_(t.Pose2D_(t.Point2D_(d.center_x, d.center_y), 0.0), d.size_x, d.size_y),
                id=d.id,
            )
            for d in vision_detections(detections)
        ]
        self._writer.write(t.Detection2DArray_(header=header, detections=items))
        self._annotations.write(self._annotations_of(result, detections, header, size))

    def _annotations_of(self, result: Result, detections: Detections, header: Any, size: tuple[int, int] | None) -> Any:
        """The result's Foxglove annotations (`foxglove.image_annotations`, built with rosbags' types as --mcap
        builds them) as the DDS type, by their CDR, which is the same bytes on both sides."""
        stamp_ns = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
        classes = result.message.get(CLASSIFICATIONS_FIELD)
        message = foxglove.image_annotations(self._store, detections, stamp_ns, size, classes)
        cdr = bytes(self._store.serialize_cdr(message, IMAGE_ANNOTATIONS))
        return self._types.ImageAnnotations_.deserialize(cdr)


class CameraResults:
    """`netapp watch URL --source NAME --ros2`: each of a camera's results published as the bridge publishes its
    own (a sink, as `--jsonl` and `--mcap` are), stamped when the netapp decoded the picture, `frame_id` the
    camera's name."""

    def __init__(
        self,
        camera: str,
        detections_topic: str = "/netapp/detections",
        annotations_topic: str = "/netapp/annotations",
        domain: int = 0,
    ) -> None:
        require("cyclonedds", NetAppError, "netapp watch --ros2")
        require("rosbags.typesys", NetAppError, "netapp watch --ros2")
        from cyclonedds.domain import DomainParticipant

        self.camera = camera
        self.published = 0
        self._participant = DomainParticipant(domain)
        self._publisher = ResultPublisher(self._participant, detections_topic, annotations_topic)

    def add(self, frame: Any, result: Result) -> None:
        self._publisher.publish(result, self._publisher.header(result.timestamp, self.camera), None)
        self.published += 1

    def close(self) -> None:
        """Nothing to flush: DDS sends as it is written."""


class Ros2Bridge:
    """Subscribes to `image_topic` (Image, or CompressedImage with `compressed`) and publishes each result on
    `detections_topic` and `annotations_topic`; counts what it receives, sends, refuses and publishes. Close it (or
    use `with`)."""

    def __init__(
        self,
        client: NetAppClient,
        image_topic: str,
        detections_topic: str = "/netapp/detections",
        domain: int = 0,
        compressed: bool = False,
        annotations_topic: str = "/netapp/annotations",
    ) -> None:
        require("cyclonedds", NetAppError, "netapp ros2")
        require("rosbags.typesys", NetAppError, "netapp ros2")
        from cyclonedds.core import Listener, Policy, Qos
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from netapp.ros import dds_types

        self.client = client
        self.counts = {"received": 0, "sent": 0, "refused": 0, "published": 0}
        self._lock = threading.Lock()
        self._pending: OrderedDict[int, tuple[Any, tuple[int, int] | None]] = OrderedDict()  # timestamp -> header, size
        self._image_type = dds_types.CompressedImage_ if compressed else dds_types.Image_
        self._msgtype = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
        self._participant = DomainParticipant(domain)
        sensor_data = Qos(
            Policy.Reliability.BestEffort, Policy.History.KeepLast(SENSOR_DATA_DEPTH), Policy.Durability.Volatile
        )
        self._publisher = ResultPublisher(self._participant, detections_topic, annotations_topic)
        client.on_result = self._publish
        self._reader = DataReader(
            self._participant,
            Topic(self._participant, dds_topic(image_topic), self._image_type),
            qos=sensor_data,
            listener=Listener(on_data_available=self._on_images),
        )

    def _on_images(self, reader: Any) -> None:
        """On a DDS thread: the newest image of those that came goes to the netapp (send never waits)."""
        # a writer's dispose or unregister comes as a sample without data (cyclonedds's InvalidSample): not an image
        samples = [s for s in reader.take(N=SENSOR_DATA_DEPTH) if hasattr(s, "data")]
        if not samples:
            return
        with self._lock:
            self.counts["received"] += len(samples)
        image = samples[-1]
        image.data = bytes(image.data)  # bytes already (dds_types.read_as_bytes), a list should that not hold
        try:
            frame = to_frame(self._msgtype, image, None)
        except ImageRefused:
            with self._lock:
                self.counts["refused"] += 1
            return
        try:
            timestamp = self.client.send(frame.wire(as_recorded=self.client.options.sending.full_frames))
        except NetAppError:
            return  # closing
        # the image's (height, width), where it was decoded: an RLE mask is traced at it
        size = frame.image.shape[:2] if frame.image is not None else None
        with self._lock:
            self.counts["sent"] += 1
            self._pending[timestamp] = image.header, size
            while len(self._pending) > PENDING:
                self._pending.popitem(last=False)

    def _publish(self, result: Result) -> None:
        with self._lock:
            header, size = self._pending.pop(result.timestamp, (None, None))
        if header is None:
            return
        self._publisher.publish(result, header, size)
        with self._lock:
            self.counts["published"] += 1

    def close(self) -> None:
        self.client.on_result = None
        self._reader.set_listener(None)

    def __enter__(self) -> Ros2Bridge:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
