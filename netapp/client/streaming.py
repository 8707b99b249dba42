"""Streaming a source to a netapp at a fixed rate, with a live progress line and a summary."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from collections.abc import Iterator
from typing import Any, TextIO

import numpy as np
import requests

from netapp.client.middleware import MiddlewareError
from netapp.client.netapp_client import NetAppClient, NetAppError
from netapp.client.sources import SourceError, open_source
from netapp.client.stats import format_summary, progress_line
from netapp.protocol import TOKEN_ENV


def stream(
    client: NetAppClient,
    frames: Iterator[np.ndarray],
    fps: float,
    duration_s: float,
    progress: TextIO | None = None,
    drain_s: float = 5.0,
) -> dict[str, Any]:
    """Send `frames` at `fps` for `duration_s`, then wait up to `drain_s` for the last results; the summary."""
    period = 1.0 / fps
    live = progress is not None and progress.isatty()
    every = 0.5 if live else 2.0  # a log file gets a line every 2 s, a terminal one line rewritten in place
    start = time.monotonic()
    next_progress = start + every
    index = 0
    for frame in frames:
        now = time.monotonic()
        if now - start >= duration_s:
            break
        client.send(frame)
        index += 1
        if progress is not None and now >= next_progress:
            progress.write(
                ("\r" if live else "") + progress_line(now - start, client.stats) + ("   " if live else "\n")
            )
            progress.flush()
            next_progress = now + every
        delay = start + index * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)  # pacing the frame rate, not synchronisation
    elapsed = time.monotonic() - start
    client.wait_idle(drain_s)
    if progress is not None:
        progress.write(("\r" if live else "") + progress_line(elapsed, client.stats) + "\n")
        progress.flush()
    return client.stats.summary(elapsed)


def stream_from_args(args: argparse.Namespace) -> int:
    size = parse_size(args.size)
    progress = None if args.json else sys.stderr
    try:
        frames = open_source(args.source, args.fps, size)
        with contextlib.ExitStack() as stack:
            client = stack.enter_context(_client_for(args, stack, progress))
            summary = stream(client, frames, args.fps, args.duration, progress)
    except (NetAppError, SourceError, MiddlewareError, TimeoutError, requests.RequestException) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    summary.update(
        transport=args.transport,
        fps=args.fps,
        url=client.url,
        urls=list(client.urls),
        policy=args.policy,
        deadline_ms=args.deadline_ms,
        link_state=client.link_state,
    )
    print(json.dumps(summary) if args.json else format_summary(summary))
    return 0 if summary["results"] > 0 else 1


def _fallback(model: str | None) -> Any:
    """The local fallback for `--fallback-model`: the netapp's detector on this machine (onnxruntime only then)."""
    if not model:
        return None
    if not os.path.isfile(model):
        raise NetAppError(f"--fallback-model {model}: no such file (give the path of an ONNX model, e.g. YOLOX-Nano)")
    from netapp.detect import Detector, DetectorConfig

    return Detector(DetectorConfig(model))


def parse_size(text: str | None) -> tuple[int, int] | None:
    if not text:
        return None
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise SystemExit(f"--size must look like 640x480, got {text!r}") from None
    return width, height


def _client_for(args: argparse.Namespace, stack: contextlib.ExitStack, progress: TextIO | None) -> NetAppClient:
    kwargs = dict(
        transport=args.transport,
        robot_id=args.robot_id,
        max_in_flight=args.max_in_flight,
        policy=args.policy,
        deadline_ms=args.deadline_ms,
        fallback=_fallback(args.fallback_model),
    )
    if progress is not None:  # what the client does, as it changes: a line of its own
        kwargs["on_switch"] = lambda s: progress.write(f"\n{s.state}: {s.reason}\n")
    if not args.middleware:
        if not args.url:
            raise NetAppError("give the netapp URL, or --middleware URL to have one deployed")
        return NetAppClient(args.url, token=args.token or os.environ.get(TOKEN_ENV) or None, **kwargs)
    from netapp.client.middleware import MiddlewareClient

    secret = args.secret or os.environ.get("NETAPP_ROBOT_SECRET")
    if not (args.robot_id and secret):
        raise NetAppError("--middleware needs --robot-id and --secret (or NETAPP_ROBOT_SECRET)")

    def show(status: dict[str, Any]) -> None:
        if progress is not None:
            progress.write(f"\rdeployment {status.get('status')}: {status.get('message') or ''}".ljust(80))
            progress.flush()

    middleware = stack.enter_context(MiddlewareClient(args.middleware, args.robot_id, secret))
    endpoint = middleware.deploy(args.app, placement=args.placement, on_progress=show)
    if progress is not None:
        progress.write(f"\rdeployed {args.app} on {endpoint.pool}: {endpoint.url}".ljust(80) + "\n")
    return middleware.netapp_client(endpoint, **kwargs)
