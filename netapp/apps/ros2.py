"""`netapp ros2`: the live ROS 2 bridge on the command line (argparse only; the bridge is imported when run)."""

from __future__ import annotations

import argparse

from netapp.client.sending_args import add_sending_arguments
from netapp.protocol import TRANSPORTS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("url", help="netapp URL, e.g. http://127.0.0.1:5896")
    parser.add_argument("--image-topic", required=True, help="the ROS 2 image topic, e.g. /camera/image_raw")
    parser.add_argument(
        "--compressed", action="store_true", help="the topic carries sensor_msgs/msg/CompressedImage (JPEG or PNG)"
    )
    parser.add_argument("--detections-topic", default="/netapp/detections", help="where Detection2DArray goes")
    parser.add_argument(
        "--annotations-topic",
        default="/netapp/annotations",
        help="where foxglove_msgs/msg/ImageAnnotations goes: masks, keypoints, oriented boxes, classes",
    )
    parser.add_argument("--domain", type=int, default=0, help="the ROS_DOMAIN_ID (default 0)")
    parser.add_argument("--transport", choices=TRANSPORTS, default="ws", help="to the netapp (default ws)")
    parser.add_argument("--max-in-flight", type=int, default=2, help="frames awaiting results at most (default 2)")
    add_sending_arguments(parser)  # paced and adaptive like `netapp stream`: --adapt, --budget-ms, --full-frames, ...
    parser.add_argument("--duration", type=float, help="seconds to run (default: until interrupted)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def run(args: argparse.Namespace) -> int:
    import json
    import signal
    import sys
    import threading

    from netapp.client.errors import NetAppError
    from netapp.client.netapp_client import NetAppClient
    from netapp.client.sending_args import sending_options
    from netapp.ros.bridge import Ros2Bridge

    try:
        client = NetAppClient(
            args.url, transport=args.transport, max_in_flight=args.max_in_flight, **sending_options(args)
        )
        with client:
            bridge = Ros2Bridge(
                client,
                args.image_topic,
                args.detections_topic,
                args.domain,
                args.compressed,
                annotations_topic=args.annotations_topic,
            )
            with bridge:
                print(f"bridging {args.image_topic} -> {args.url} -> {args.detections_topic}", file=sys.stderr)
                stop = threading.Event()
                if threading.current_thread() is threading.main_thread():
                    # A container stops with SIGTERM: end as Ctrl-C does, with the summary.
                    signal.signal(signal.SIGTERM, lambda *_: stop.set())
                try:
                    stop.wait(args.duration)  # the bridge works on DDS and client threads
                except KeyboardInterrupt:
                    pass
                client.wait_idle(2.0)
            summary = {**bridge.counts, "latency_ms": client.stats.summary(1.0)["latency_ms"]}
            adapt = client.adapt_report()
            if adapt is not None:
                summary["adapt"] = adapt
    except NetAppError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(summary) if args.json else " ".join(f"{k} {v}" for k, v in summary.items()))
    return 0 if summary["published"] else 1
