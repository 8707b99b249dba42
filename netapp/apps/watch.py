"""`netapp watch`: print the results of a camera a netapp pulls, or write them (JSON lines, MCAP) as `netapp stream`
does a robot's."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("url", help="the netapp's URL, e.g. http://127.0.0.1:5896")
    parser.add_argument("--source", required=True, help="the camera's name (netapp serve --source NAME=rtsp://...)")
    parser.add_argument("--jsonl", metavar="FILE", help="write one JSON line per result (as netapp stream --jsonl)")
    parser.add_argument(
        "--mcap", metavar="OUT.mcap", help="write the detections as ROS 2 messages, as netapp stream --mcap (no images)"
    )
    parser.add_argument(
        "--ros2",
        action="store_true",
        help="publish each result over DDS with ROS 2's names, as `netapp ros2` does (vision_msgs on "
        "--detections-topic, foxglove annotations on --annotations-topic; frame_id the camera's name; the ros extra)",
    )
    parser.add_argument("--detections-topic", default="/netapp/detections", help="with --ros2 (default %(default)s)")
    parser.add_argument("--annotations-topic", default="/netapp/annotations", help="with --ros2 (default %(default)s)")
    parser.add_argument("--domain", type=int, default=0, help="with --ros2: the ROS_DOMAIN_ID (default 0)")
    parser.add_argument("--count", type=int, help="stop after this many results (default: run until stopped)")
    parser.add_argument("--duration", type=float, help="stop after this many seconds (default: run until stopped)")
    parser.add_argument("--token", help="the netapp's token, if it needs one (or NETAPP_TOKEN)")


def run(args: argparse.Namespace) -> int:
    import contextlib
    import json
    import logging
    import os
    import time

    from netapp.apps.streaming import open_sinks
    from netapp.client.errors import NetAppError, OutputError
    from netapp.client.watch import camera_result, subscribe
    from netapp.protocol import TOKEN_ENV

    log = logging.getLogger("netapp.watch")
    deadline = time.monotonic() + args.duration if args.duration else None
    seen = 0
    with contextlib.ExitStack() as stack:
        try:
            sinks = open_sinks(args, stack)  # --jsonl, --mcap; none: each result printed
            if args.ros2:
                from netapp.ros.bridge import CameraResults

                sinks.append(CameraResults(args.source, args.detections_topic, args.annotations_topic, args.domain))
            subscription = subscribe(args.url, args.source, args.token or os.environ.get(TOKEN_ENV) or None)
            stack.callback(subscription.close)
            for message in subscription.results(until=deadline):
                result = camera_result(message, args.url)
                if not sinks:
                    print(json.dumps(message, separators=(",", ":")), flush=True)
                for sink in sinks if result is not None else ():
                    sink.add(None, result)
                seen += 1
                if args.count and seen >= args.count:
                    break
        except (NetAppError, OutputError) as exc:
            log.error("%s", exc)
            return 1
    log.info("%d results of camera %s", seen, args.source)
    return 0
