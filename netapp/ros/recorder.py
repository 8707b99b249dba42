"""`--mcap OUT`: an MCAP that opens in Foxglove with the boxes on the images (`docs/ros.md#write-an-mcap`).

Per result, all stamped with the source image's header stamp (a recording) or its capture time (a video, a camera):

* the image as `sensor_msgs/msg/CompressedImage` (ROS 2 CDR): its recorded JPEG or PNG bytes as they are, else
  the frame JPEG-encoded;
* `vision_msgs/msg/Detection2DArray` on `/netapp/detections`: class name as `class_id`, score, the box in the
  image's pixels, the track id in the detection's `id` (the tracking netapp);
* `foxglove_msgs/msg/ImageAnnotations` on `/netapp/annotations`, laid over the image by Foxglove's Image panel: boxes
  and labels, masks as filled polygons, keypoints as points with the skeleton's limbs, oriented boxes, classes;
* `netapp_msgs/msg/Latency` on `/netapp/latency`: the latency and its parts, for a Plot panel.

Every message is ROS 2 CDR with its definition in the file (`ros2msg`), so rosbags and mcap-ros2-support read it.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from netapp.client.delivery import Result
from netapp.client.errors import OutputError
from netapp.client.frames import SourceFrame
from netapp.detections import Detections
from netapp.results import CLASSIFICATIONS_FIELD
from netapp.ros import foxglove, require
from netapp.ros.detections import vision_detections
from netapp.ros.messages import COMPRESSED_IMAGE, DETECTION_ARRAY, IMAGE_ANNOTATIONS, LATENCY, header, typestore

IMAGE_TOPIC = "/netapp/image"
DETECTIONS_TOPIC = "/netapp/detections"
ANNOTATIONS_TOPIC = "/netapp/annotations"
LATENCY_TOPIC = "/netapp/latency"


class McapRecorder:
    """Writes each (frame, result) to an MCAP; a sink of `netapp stream --mcap`, and for robot code:

    with McapRecorder("run.mcap") as recording:
        recording.add(frame, result)   # a SourceFrame or a BGR array, and its Result
    """

    needs_frames = True

    def __init__(self, path: str, jpeg_quality: int = 85, image_topic: str = IMAGE_TOPIC) -> None:
        writer_module = require("mcap.writer", OutputError, "--mcap")
        require("rosbags.typesys", OutputError, "--mcap")
        self._store = typestore()
        try:
            self._file = open(path, "wb")  # closed by close()
        except OSError as exc:
            raise OutputError(f"cannot write --mcap {path}: {exc.strerror}") from None
        self.path, self.jpeg_quality, self.messages = path, jpeg_quality, 0
        self._writer = writer_module.Writer(self._file)
        self._writer.start(profile="ros2", library="netapp-toolkit")
        self._sequence: dict[int, int] = {}
        self._image = self._ros_channel(image_topic, COMPRESSED_IMAGE)
        self._detections = self._ros_channel(DETECTIONS_TOPIC, DETECTION_ARRAY)
        self._annotations = self._ros_channel(ANNOTATIONS_TOPIC, IMAGE_ANNOTATIONS)
        self._latency = self._ros_channel(LATENCY_TOPIC, LATENCY)

    def _ros_channel(self, topic: str, msgtype: str) -> int:
        msgdef, _ = self._store.generate_msgdef(msgtype, ros_version=2)
        schema = self._writer.register_schema(msgtype, "ros2msg", msgdef.encode())
        return self._writer.register_channel(topic, "cdr", schema)

    def _write(self, channel: int, stamp_ns: int, data: bytes) -> None:
        sequence = self._sequence.get(channel, 0)
        self._writer.add_message(channel, log_time=stamp_ns, data=data, publish_time=stamp_ns, sequence=sequence)
        self._sequence[channel] = sequence + 1
        self.messages += 1

    def _cdr(self, message: Any, msgtype: str) -> bytes:
        return bytes(self._store.serialize_cdr(message, msgtype))

    def add(self, frame: SourceFrame | np.ndarray | None, result: Result) -> None:
        if isinstance(frame, np.ndarray):
            frame = SourceFrame(result.timestamp, frame)
        stamp_ns = result.source_stamp_ns
        if stamp_ns is None:
            stamp_ns = frame.stamp_ns if frame is not None else result.timestamp
        frame_id = frame.frame_id if frame is not None else ""
        if frame is not None:
            self._write(self._image, stamp_ns, self._cdr(self.compressed_image(frame, stamp_ns), COMPRESSED_IMAGE))
        detections = Detections.from_wire(result.detections, strict=False)
        array = detection_array(self._store, detections, stamp_ns, frame_id)
        self._write(self._detections, stamp_ns, self._cdr(array, DETECTION_ARRAY))
        size = frame.bgr().shape[:2] if frame is not None and detections.has_rle() else None
        classes = result.message.get(CLASSIFICATIONS_FIELD) if isinstance(result.message, dict) else None
        annotations = foxglove.image_annotations(self._store, detections, stamp_ns, size, classes)
        self._write(self._annotations, stamp_ns, self._cdr(annotations, IMAGE_ANNOTATIONS))
        latency = foxglove.latency(self._store, result, stamp_ns, frame_id)
        self._write(self._latency, stamp_ns, self._cdr(latency, LATENCY))

    def compressed_image(self, frame: SourceFrame, stamp_ns: int) -> Any:
        """The recorded bytes as they are, else the frame as JPEG."""
        if frame.encoded is not None and frame.format in ("jpeg", "png"):
            data, fmt = frame.encoded, frame.format
        else:
            ok, buf = cv2.imencode(".jpg", frame.bgr(), [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
            if not ok:
                raise OutputError("--mcap: could not encode a frame as JPEG")
            data, fmt = buf.tobytes(), "jpeg"
        return self._store.types[COMPRESSED_IMAGE](
            header=header(self._store, stamp_ns, frame.frame_id), format=fmt, data=np.frombuffer(data, np.uint8)
        )

    def close(self) -> None:
        if self._file.closed:
            return
        self._writer.finish()
        self._file.close()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def detection_array(store: Any, detections: Detections | list[Any], stamp_ns: int, frame_id: str) -> Any:
    """`vision_msgs/msg/Detection2DArray` of a result's detections (`netapp/ros/detections.py`)."""
    t = store.types
    stamped = header(store, stamp_ns, frame_id)
    pose = t["geometry_msgs/msg/PoseWithCovariance"](
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        covariance=np.zeros(36, np.float64),
    )
    items = [
        t["vision_msgs/msg/Detection2D"](
            header=stamped,
            results=[
                t["vision_msgs/msg/ObjectHypothesisWithPose"](
                    hypothesis=t["vision_msgs/msg/ObjectHypothesis"](class_id=d.class_id, score=d.score), pose=pose
                )
            ],
            bbox=t["vision_msgs/msg/BoundingBox2D"](
                center=t["vision_msgs/msg/Pose2D"](
                    position=t["vision_msgs/msg/Point2D"](x=d.center_x, y=d.center_y), theta=0.0
                ),
                size_x=d.size_x,
                size_y=d.size_y,
            ),
            id=d.id,
        )
        for d in vision_detections(detections)
    ]
    return t[DETECTION_ARRAY](header=stamped, detections=items)
