"""`netapp stream`: the robot side on the command line."""

from __future__ import annotations

import argparse

from netapp.client.options import CODECS, transport_and_codec
from netapp.client.policy import POLICIES
from netapp.client.sending_args import add_sending_arguments
from netapp.protocol import TRANSPORTS, WEBRTC_TRANSPORT


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "url",
        nargs="*",
        help="netapp URL, e.g. http://127.0.0.1:5896; several: in order of preference (or use --middleware)",
    )
    parser.add_argument(
        "--transport",
        choices=(*TRANSPORTS, WEBRTC_TRANSPORT),
        default="ws",
        help="http (POST per frame), ws (Socket.IO, 5G-ERA) or frames (binary frames on a plain WebSocket, the "
        "leanest; docs/protocol.md); h264 is the shorthand for ws with --codec h264; rtp sends H.264 over RTP/UDP, "
        "its session and results on frames (a netapp with --rtp-ports; docs/cameras.md#rtp-push); webrtc sends a "
        "WebRTC video track, its results on a data channel (the webrtc extra; docs/cameras.md#webrtc)",
    )
    parser.add_argument(
        "--codec",
        choices=CODECS,
        help="jpeg (a JPEG per frame, the default) or h264 (an H.264 stream per netapp, needs ws or frames)",
    )
    parser.add_argument(
        "--source",
        required=True,
        help="video file, image file, camera index, or a recording: a ROS 2 bag folder, .mcap or ROS 1 .bag",
    )
    parser.add_argument("--topic", help="the recording's image topic (default: its first image topic)")
    parser.add_argument(
        "--rate",
        type=float,
        default=1.0,
        help="replay a recording at this times its recorded rate (default 1; 0: as fast as the netapp answers)",
    )
    parser.add_argument("--fps", type=float, default=10.0, help="frames per second to send (default 10)")
    parser.add_argument("--duration", type=float, help="seconds to stream (default 10; a recording: to its end)")
    parser.add_argument("--size", help="resize frames to WIDTHxHEIGHT, e.g. 640x480")
    parser.add_argument("--max-in-flight", type=int, default=2, help="frames awaiting results at most (default 2)")
    parser.add_argument(
        "--policy",
        choices=POLICIES,
        default="primary",
        help="with several URLs: primary (fail over and back), hedge (every frame to all, first result wins) or "
        "adaptive (hedge while the first netapp misses deadlines); default primary",
    )
    parser.add_argument("--deadline-ms", type=float, help="a result older than this is late (sent to the netapps)")
    add_sending_arguments(parser)
    parser.add_argument(
        "--fallback-model", help="ONNX model run on this machine while no netapp meets the deadline (needs onnxruntime)"
    )
    parser.add_argument("--robot-id", help="robot id (sent with INIT / register; needed with --middleware)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON, no progress line")
    parser.add_argument("--save", metavar="OUT.mp4", help="write the frames with their boxes and latency drawn (mp4v)")
    parser.add_argument("--jsonl", metavar="FILE", help="write one JSON line per result (detections, latency parts)")
    parser.add_argument(
        "--mcap",
        metavar="OUT.mcap",
        help="write images, vision_msgs detections, Foxglove annotations and latency to an MCAP (ros extra)",
    )
    parser.add_argument("--show", action="store_true", help="show the annotated frames in a window (needs a display)")
    parser.add_argument("--token", help="the netapp's token, if it needs one (or NETAPP_TOKEN)")
    parser.add_argument(
        "--ice-server",
        action="append",
        default=[],
        metavar="URL",
        help="--transport webrtc: a STUN or TURN server (turn: credentials from $NETAPP_ICE_USERNAME and "
        "$NETAPP_ICE_CREDENTIAL), repeatable; default none",
    )
    parser.add_argument(
        "--ice-address",
        action="append",
        default=[],
        metavar="ADDRESS",
        help="--transport webrtc: offer only this local address as a candidate, repeatable (e.g. 127.0.0.1 for a "
        "netapp on this machine); default every address but loopback",
    )
    parser.add_argument("--middleware", help="middleware URL: ask it for a netapp instead of giving a URL")
    parser.add_argument("--app", default="object-detection", help="catalogue app to deploy (with --middleware)")
    parser.add_argument("--placement", default="auto", help="edge, cloud, auto or a pool name (with --middleware)")
    parser.add_argument("--secret", help="robot secret (with --middleware; or NETAPP_ROBOT_SECRET)")


def run(args: argparse.Namespace) -> int:
    from netapp.apps.streaming import stream_from_args

    if args.transport == WEBRTC_TRANSPORT:
        if args.codec is not None:
            raise SystemExit("error: the webrtc transport negotiates its own codec: leave --codec out")
        return stream_from_args(args)
    try:
        transport_and_codec(args.transport, args.codec)  # a combination that does not exist, before any work
    except ValueError as exc:
        raise SystemExit(f"error: {exc}") from None

    return stream_from_args(args)
