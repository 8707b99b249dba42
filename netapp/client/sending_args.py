"""How a robot sends its frames, on the command line: the options `netapp stream` and `netapp ros2` share (argparse
only), and the `NetAppClient` keywords they make."""

from __future__ import annotations

import argparse
from typing import Any

from netapp.accuracy import DEFAULT_F1_FLOOR
from netapp.client.adapt.controller import DEFAULT_BUDGET_MS
from netapp.client.options import ADAPT_MODES


def add_sending_arguments(parser: argparse.ArgumentParser) -> None:
    """How a robot sends its frames (the size, and the uplink's adaptation): the same for `netapp stream` and
    `netapp ros2`; `sending_options` turns them into `NetAppClient` keywords."""
    parser.add_argument(
        "--full-frames",
        action="store_true",
        help="send frames at their own size, not fitted to the netapp's processor input (docs/client.md#what-is-sent)",
    )
    parser.add_argument(
        "--adapt",
        choices=ADAPT_MODES,
        default="auto",
        help="auto (the default): choose frame size, JPEG quality or H.264 bitrate, and frame rate from what the "
        "uplink carries, within --budget-ms and above --accuracy-floor, and JPEG or H.264 where the transport carries "
        "both (ws, frames; H.264 needs PyAV); auto-one-codec: the same in the transport's own codec; off: send every "
        "frame as it comes",
    )
    parser.add_argument(
        "--budget-ms",
        type=float,
        default=DEFAULT_BUDGET_MS,
        help=f"the latency the uplink adapts to (default {DEFAULT_BUDGET_MS:g})",
    )
    parser.add_argument(
        "--accuracy-floor",
        type=float,
        default=DEFAULT_F1_FLOOR,
        help=f"the least F1 (against full quality) the uplink may trade for bytes (default {DEFAULT_F1_FLOOR:g})",
    )


def sending_options(args: argparse.Namespace) -> dict[str, Any]:
    """The `NetAppClient` keywords of `add_sending_arguments`."""
    return dict(
        full_frames=args.full_frames,
        adapt=args.adapt,
        latency_budget_ms=args.budget_ms,
        accuracy_floor=args.accuracy_floor,
    )
