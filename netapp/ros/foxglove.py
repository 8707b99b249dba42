"""A result as `foxglove_msgs/msg/ImageAnnotations` (laid over the image by Foxglove's Image panel: boxes and labels,
masks as filled polygons, keypoints as points and the skeleton's limbs as a line list, oriented boxes, an image
classification's top classes) and as `netapp_msgs/msg/Latency` (its latency parts, for a Plot panel): ROS 2 messages
like the rest of the MCAP, so every reader of ROS 2 recordings decodes them. The live ROS 2 bridge publishes the same
annotations (netapp/ros/bridge.py)."""

from __future__ import annotations

from typing import Any

from netapp.client.draw import CAPTION_CLASSES, class_colour, classification_caption
from netapp.detections import Detections, as_detections
from netapp.results import MASK_ALPHA, RLE_KEY
from netapp.ros.messages import IMAGE_ANNOTATIONS, LATENCY, header, stamp

# foxglove_msgs/msg/PointsAnnotation's types
POINTS, LINE_LOOP, LINE_LIST = 1, 2, 4
KEYPOINT_SIZE = 6.0  # a keypoint's diameter in pixels (a POINTS annotation's thickness)


def rgba(class_id: Any, alpha: float = 1.0) -> tuple[float, float, float, float]:
    """The class's colour (the one `--save` draws it in) as r, g, b, a in 0..1."""
    b, g, r = class_colour(class_id if isinstance(class_id, int) else 0)
    return r / 255, g / 255, b / 255, alpha


def image_annotations(
    store: Any,
    detections: Detections | list[Any],
    stamp_ns: int,
    size: tuple[int, int] | None = None,
    classifications: Any = None,
) -> Any:
    """Per detection, in the image's pixels and stamped like the image: its box (a line loop) and `class score`
    label; its mask as filled line loops (an RLE traced at the image's `size`, (height, width), or at its own);
    its sure keypoints as POINTS and the skeleton's limbs as a LINE_LIST; its oriented box as a line loop. An image
    classification's top classes as a text at the top left. `detections` is a `Detections` or the wire list, read
    leniently: what is malformed is left out."""
    t = store.types
    when = stamp(store, stamp_ns)
    dets = as_detections(detections)

    def colour(values: tuple[float, float, float, float]) -> Any:
        return t["foxglove_msgs/msg/Color"](*values)

    def point(x: float, y: float) -> Any:
        return t["foxglove_msgs/msg/Point2"](x=x, y=y)

    def shape(kind: int, xy: list[tuple[float, float]], class_id: int, fill: float = 0.0, width: float = 2.0):
        return t["foxglove_msgs/msg/PointsAnnotation"](
            timestamp=when,
            type=kind,
            points=[point(x, y) for x, y in xy],
            outline_color=colour(rgba(class_id)),
            outline_colors=[],
            fill_color=colour(rgba(class_id, fill)),
            thickness=width,
        )

    points, texts = [], []
    corners, oriented = dets.rbox_corners().tolist(), dets.has_rbox()
    for i, (x1, y1, x2, y2) in enumerate(dets.xyxy.tolist()):
        class_id = max(0, int(dets.class_id[i]))
        if dets.masks[i] is not None:
            height, width = size or _rle_size(dets.masks[i])
            for polygon in dets.mask_outlines(i, height, width):
                xy = list(zip(polygon[0::2], polygon[1::2], strict=True))
                points.append(shape(LINE_LOOP, xy, class_id, fill=MASK_ALPHA, width=1.0))
        points.append(shape(LINE_LOOP, [(x1, y1), (x2, y1), (x2, y2), (x1, y2)], class_id))
        if oriented[i]:
            points.append(shape(LINE_LOOP, corners[i], class_id))
        sure, limbs = dets.pose(i)
        if limbs:
            points.append(shape(LINE_LIST, [end for limb in limbs for end in limb], class_id))
        if sure:
            points.append(shape(POINTS, sure, class_id, fill=1.0, width=KEYPOINT_SIZE))
        track = dets.tracker_id[i] if dets.tracker_id is not None else -1
        label = dets.label(i) + (f" #{track}" if track >= 0 else "")
        texts.append(
            t["foxglove_msgs/msg/TextAnnotation"](
                timestamp=when,
                position=point(x1, max(y1 - 4.0, 0.0)),
                text=label,
                font_size=14.0,
                text_color=colour((1.0, 1.0, 1.0, 1.0)),
                background_color=colour(rgba(class_id)),
            )
        )
    caption = classification_caption(classifications, CAPTION_CLASSES)
    if caption:
        texts.append(
            t["foxglove_msgs/msg/TextAnnotation"](
                timestamp=when,
                position=point(4.0, 16.0),
                text=caption,
                font_size=14.0,
                text_color=colour((1.0, 1.0, 1.0, 1.0)),
                background_color=colour((0.0, 0.0, 0.0, 0.7)),
            )
        )
    return t[IMAGE_ANNOTATIONS](circles=[], points=points, texts=texts)


def _rle_size(mask: Any) -> tuple[int, int]:
    """An RLE mask's own (height, width) (checked by `Detections.from_wire`), where the image's size is not known;
    (0, 0) for polygons, which need none."""
    if isinstance(mask, dict) and RLE_KEY in mask:
        height, width = mask[RLE_KEY]["size"]
        return height, width
    return (0, 0)


def latency(store: Any, result: Any, stamp_ns: int, frame_id: str) -> Any:
    """The result's latency and its parts (0 where the netapp did not stamp them), stamped like the image."""
    parts = result.breakdown.as_dict() if result.breakdown is not None else {}
    return store.types[LATENCY](
        header=header(store, stamp_ns, frame_id),
        latency_ms=float(result.latency_ms),
        uplink_ms=float(parts.get("uplink_ms", 0.0)),
        queue_ms=float(parts.get("queue_ms", 0.0)),
        inference_ms=float(parts.get("inference_ms", 0.0)),
        downlink_ms=float(parts.get("downlink_ms", 0.0)),
        source=result.source,
        late=bool(result.late),
    )
