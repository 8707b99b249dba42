"""A result as `foxglove_msgs/msg/ImageAnnotations` (its boxes and labels, laid over the image by Foxglove's Image
panel) and as `netapp_msgs/msg/Latency` (its latency parts, for a Plot panel): ROS 2 messages like the rest of the
MCAP, so every reader of ROS 2 recordings decodes them."""

from __future__ import annotations

from typing import Any

from netapp.client.draw import class_colour, label_of
from netapp.ros.messages import IMAGE_ANNOTATIONS, LATENCY, header, stamp

LINE_LOOP = 2  # foxglove_msgs/msg/PointsAnnotation.LINE_LOOP


def rgba(class_id: Any, alpha: float = 1.0) -> tuple[float, float, float, float]:
    """The class's colour (the one `--save` draws it in) as r, g, b, a in 0..1."""
    b, g, r = class_colour(class_id if isinstance(class_id, int) else 0)
    return r / 255, g / 255, b / 255, alpha


def image_annotations(store: Any, detections: list[dict[str, Any]], stamp_ns: int) -> Any:
    """A box (line loop) and a `class score` label per detection, in the image's pixels, stamped like the image."""
    t = store.types
    when = stamp(store, stamp_ns)

    def colour(values: tuple[float, float, float, float]) -> Any:
        return t["foxglove_msgs/msg/Color"](*values)

    def point(x: float, y: float) -> Any:
        return t["foxglove_msgs/msg/Point2"](x=x, y=y)

    points, texts = [], []
    for d in detections:
        if not isinstance(d, dict) or "bbox" not in d:
            continue  # a custom processor's output
        x1, y1, x2, y2 = (float(v) for v in d["bbox"])
        points.append(
            t["foxglove_msgs/msg/PointsAnnotation"](
                timestamp=when,
                type=LINE_LOOP,
                points=[point(x1, y1), point(x2, y1), point(x2, y2), point(x1, y2)],
                outline_color=colour(rgba(d.get("class"))),
                outline_colors=[],
                fill_color=colour(rgba(d.get("class"), 0.0)),
                thickness=2.0,
            )
        )
        label = label_of(d) + (f" #{d['track_id']}" if d.get("track_id") is not None else "")
        texts.append(
            t["foxglove_msgs/msg/TextAnnotation"](
                timestamp=when,
                position=point(x1, max(y1 - 4.0, 0.0)),
                text=label,
                font_size=14.0,
                text_color=colour((1.0, 1.0, 1.0, 1.0)),
                background_color=colour(rgba(d.get("class"))),
            )
        )
    return t[IMAGE_ANNOTATIONS](circles=[], points=points, texts=texts)


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
