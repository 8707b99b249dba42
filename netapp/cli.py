"""The `netapp` command: one entry point, one subcommand per part.

Each part registers its own arguments in a light module (argparse only) and imports its implementation lazily,
so `netapp stream` runs on a robot without the server's dependencies installed. Only the module of the command
named is imported (`netapp serve` imports no robot client, `netapp stream` no server); `netapp --help` imports all.
The robot's applications live in netapp/apps/, which nothing else imports.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from netapp import __version__

# subcommand -> module defining `add_arguments(parser)` and `run(args) -> int`
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "serve": (
        "netapp.server.cli",
        "serve detection (or another SDK processor) over HTTP, Socket.IO, frames, RTP and WebRTC",
    ),
    "model": ("netapp.apps.model", "inspect a model: what the netapp recognises in it, and why"),
    "stream": ("netapp.apps.stream", "stream a camera, video or image to a netapp and report latency"),
    "watch": ("netapp.apps.watch", "print the results of a camera a netapp pulls (netapp serve --source)"),
    "rollout": ("netapp.apps.rollout", "show a netapp's model rollout (netapp serve --candidate)"),
    "profile": ("netapp.apps.profile", "measure a model's accuracy profile (frame size and JPEG quality)"),
    "ros2": ("netapp.apps.ros2", "bridge a ROS 2 image topic to a netapp over DDS, publishing vision_msgs detections"),
    "operator": ("netapp_operator.cli", "run the Kubernetes operator that reconciles NetApps and NodePools"),
    "middleware": ("netapp_middleware.cli", "run the robot-facing middleware API"),
}


def command_in(argv: list[str]) -> str | None:
    """The subcommand `argv` names: its first word after the global options (None when that is no command, or when
    the global help is asked for, which lists every command)."""
    words = iter(argv)
    for word in words:
        if word in ("-h", "--help"):
            return None
        if word == "--log-level":
            next(words, None)  # its value
        elif not word.startswith("-"):
            return word if word in SUBCOMMANDS else None
    return None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every installed subcommand, or of `command` alone (importing only its module)."""
    parser = argparse.ArgumentParser(prog="netapp", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"netapp {__version__}")
    parser.add_argument("--log-level", default="INFO", help="logging level (default INFO)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        if command is not None and name != command:
            continue
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            if command is not None:
                return build_parser()  # that part is not installed here: the error lists those that are
            continue  # that part is not installed here
        sub_parser = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(sub_parser)
        sub_parser.set_defaults(run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(command_in(argv)).parse_args(argv)
    logging.basicConfig(
        level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )
    try:
        return int(args.run(args) or 0)
    except KeyboardInterrupt:
        return 130
