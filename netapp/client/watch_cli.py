"""`netapp watch`: print (or write to a JSON-lines file) the results of a camera a netapp pulls."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("url", help="the netapp's URL, e.g. http://127.0.0.1:5896")
    parser.add_argument("--source", required=True, help="the camera's name (netapp serve --source NAME=rtsp://...)")
    parser.add_argument("--jsonl", help="write each result as one JSON line to this file (default: print them)")
    parser.add_argument("--count", type=int, help="stop after this many results (default: run until stopped)")
    parser.add_argument("--duration", type=float, help="stop after this many seconds (default: run until stopped)")
    parser.add_argument("--token", help="the netapp's token, if it needs one (or NETAPP_TOKEN)")


def run(args: argparse.Namespace) -> int:
    import json
    import logging
    import os
    import sys
    import time

    from netapp.client.errors import NetAppError
    from netapp.client.watch import Subscription
    from netapp.protocol import TOKEN_ENV

    log = logging.getLogger("netapp.watch")
    out = open(args.jsonl, "a", encoding="utf-8") if args.jsonl else sys.stdout  # noqa: SIM115 (closed below)
    deadline = time.monotonic() + args.duration if args.duration else None
    seen = 0
    try:
        subscription = Subscription(args.url, args.source, args.token or os.environ.get(TOKEN_ENV) or None)
    except NetAppError as exc:
        log.error("%s", exc)
        return 1
    try:
        for result in subscription.results(until=deadline):
            out.write(json.dumps(result, separators=(",", ":")) + "\n")
            out.flush()
            seen += 1
            if args.count and seen >= args.count:
                break
    except NetAppError as exc:
        log.error("%s", exc)
        return 1
    finally:
        subscription.close()
        if out is not sys.stdout:
            out.close()
    log.info("%d results of camera %s", seen, args.source)
    return 0
