"""Command line: run one emulated link until Ctrl-C, or measure every profile.

    python -m bench.linkemu --profile 5g --target 127.0.0.1:8000 --listen 127.0.0.1:9000
    python -m bench.linkemu --profile 5g --target 127.0.0.1:8000 --outage 3/20 --change 30:delay=150
    python -m bench.linkemu --profile 5g --target 127.0.0.1:8000 --change 20:up=1.5 --trace uplink.txt
    python -m bench.linkemu check [--profile wifi ...] [--mode userspace]

(from the repository root).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from collections.abc import Callable

from .emulator import LinkEmulator
from .profiles import PROFILES
from .schedule import CHANGE_FORMAT, LinkSchedule, parse_change, parse_outages, read_trace


def _hostport(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host, int(port)


def _parsed(parse: Callable[[str], object]) -> Callable[[str], object]:
    def convert(text: str) -> object:
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return convert


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _take_stop_signals() -> None:
    """Make SIGINT and SIGTERM wait for :func:`signal.sigwait` in this thread, whatever the caller set.

    Call before any thread starts: threads inherit the mask, so no other thread can take the signal. A signal
    caught by a handler goes to any thread that does not block it, and one that lands on the relay's thread never
    wakes the main thread's wait (the CLI would hang); and a SIGINT ignored by the parent (``sh -c 'cmd &'`` does
    that) would make Ctrl-C do nothing.
    """
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    for sig in STOP_SIGNALS:
        # Not ignored, so the kernel keeps it pending for sigwait; never run, as it stays blocked.
        signal.signal(sig, signal.SIG_DFL)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    modes = ["auto", "netns", "userspace"]
    if argv[:1] == ["check"]:
        ap = argparse.ArgumentParser(
            prog="python -m bench.linkemu check", description="measure each profile, print a Markdown table"
        )
        ap.add_argument(
            "--profile", action="append", choices=list(PROFILES), help="profile to measure (repeatable; default: all)"
        )
        ap.add_argument("--mode", choices=modes, default="auto")
        ap.add_argument("--samples", type=int, default=50, help="echo round trips per profile")
        ap.add_argument("--bulk-seconds", type=float, default=1.5, help="target duration of each bulk transfer")
        args = ap.parse_args(argv[1:])
        from .check import run_check

        # Ctrl-C and SIGTERM unwind the measurement (so its namespaces are deleted), also when the parent ignored
        # SIGINT. The main thread is busy measuring, so it sees the signal whichever thread the kernel picks.
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.default_int_handler)
        try:
            print(run_check(args.profile, args.mode, args.samples, args.bulk_seconds))
        except KeyboardInterrupt:
            return 130
        return 0

    ap = argparse.ArgumentParser(
        prog="python -m bench.linkemu", description="emulate a link in front of a TCP server until Ctrl-C"
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
    ap.add_argument(
        "--outage", type=_parsed(parse_outages), help="DOWN/EVERY[+FIRST] seconds: 3/20 is 3 s down every 20 s"
    )
    ap.add_argument(
        "--change",
        type=_parsed(parse_change),
        action="append",
        default=[],
        help=f"{CHANGE_FORMAT}: from T seconds on (repeatable), e.g. 30:delay=150 or 20:up=1.5",
    )
    ap.add_argument(
        "--trace",
        type=_parsed(read_trace),
        default=(),
        help="a file of TIME UP DOWN rows (seconds, Mbit/s): the link's rates over time, with --change's figures",
    )
    args = ap.parse_args(argv)
    _take_stop_signals()  # a signal during set-up stays pending: the link is built, then torn down at once
    schedule = LinkSchedule((*args.trace, *args.change), args.outage)
    emu = LinkEmulator(
        PROFILES[args.profile], args.target, listen=args.listen, mode=args.mode, seed=args.seed, schedule=schedule
    )
    with emu as (host, port):
        print(
            f"linkemu: {args.profile} ({emu.mode}) listening on {host}:{port} -> "
            f"{args.target[0]}:{args.target[1]}; Ctrl-C to stop",
            flush=True,
        )
        signum = signal.sigwait(STOP_SIGNALS)
    print(f"linkemu: stopped by {signal.Signals(signum).name}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
