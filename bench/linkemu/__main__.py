"""Command line: run one emulated link until Ctrl-C, or measure every profile.

    python -m linkemu --profile 5g --target 127.0.0.1:8000 --listen 127.0.0.1:9000
    python -m linkemu check [--profile wifi ...] [--mode userspace]

(run from ``bench/``, or with ``bench`` on PYTHONPATH; ``python bench/linkemu_check.py`` works
from the repository root).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from types import FrameType

from .emulator import LinkEmulator
from .profiles import PROFILES


def _hostport(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host, int(port)


def _sigterm(signum: int, frame: FrameType | None) -> None:
    # Turn SIGTERM into the same unwinding as Ctrl-C so the namespaces are deleted.
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    signal.signal(signal.SIGTERM, _sigterm)
    modes = ["auto", "netns", "userspace"]
    if argv[:1] == ["check"]:
        ap = argparse.ArgumentParser(
            prog="python -m linkemu check", description="measure each profile, print a Markdown table"
        )
        ap.add_argument(
            "--profile", action="append", choices=list(PROFILES), help="profile to measure (repeatable; default: all)"
        )
        ap.add_argument("--mode", choices=modes, default="auto")
        ap.add_argument("--samples", type=int, default=50, help="echo round trips per profile")
        ap.add_argument("--bulk-seconds", type=float, default=1.5, help="target duration of each bulk transfer")
        args = ap.parse_args(argv[1:])
        from .check import run_check

        try:
            print(run_check(args.profile, args.mode, args.samples, args.bulk_seconds))
        except KeyboardInterrupt:
            return 130
        return 0

    ap = argparse.ArgumentParser(
        prog="python -m linkemu", description="emulate a link in front of a TCP server until Ctrl-C"
    )
    ap.add_argument("--profile", choices=list(PROFILES), required=True)
    ap.add_argument("--target", type=_hostport, required=True, help="server HOST:PORT")
    ap.add_argument(
        "--listen",
        type=_hostport,
        default=("127.0.0.1", 0),
        help="where clients connect (default 127.0.0.1:<ephemeral>)",
    )
    ap.add_argument("--mode", choices=modes, default="auto")
    ap.add_argument("--seed", type=int, default=None, help="seed for jitter and loss")
    args = ap.parse_args(argv)
    emu = LinkEmulator(PROFILES[args.profile], args.target, listen=args.listen, mode=args.mode, seed=args.seed)
    try:
        with emu as (host, port):
            print(
                f"linkemu: {args.profile} ({emu.mode}) listening on {host}:{port} -> "
                f"{args.target[0]}:{args.target[1]}; Ctrl-C to stop",
                flush=True,
            )
            threading.Event().wait()  # until a signal interrupts
    except KeyboardInterrupt:
        print("linkemu: stopped", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
