"""Streaming a source to a netapp at a fixed rate, with a live progress line, per-result outputs and a summary."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from typing import Any, TextIO

import numpy as np
import requests

from netapp.apps.outputs import AnnotatedVideo, JsonLines, Sink, Window, processor_output
from netapp.client.errors import OutputError
from netapp.client.frames import SourceFrame
from netapp.client.middleware import MiddlewareError
from netapp.client.netapp_client import NetAppClient, NetAppError
from netapp.client.sending_args import sending_options
from netapp.client.sources import SourceError, open_source
from netapp.client.stats import format_summary, no_results_line, progress_line
from netapp.client.urls import BadURL
from netapp.protocol import TOKEN_ENV, WEBRTC_TRANSPORT

# What a person can cause (a wrong URL, source or path, an unreachable netapp): one line, exit code 1.
DEFAULT_DURATION_S = 10.0  # a video, an image or a camera; a recording plays to its end
USER_ERRORS = (NetAppError, SourceError, MiddlewareError, OutputError, BadURL, TimeoutError, requests.RequestException)


class Progress:
    """Status lines on stderr: on a terminal one line rewritten in place, ended before anything else is printed."""

    def __init__(self, out: TextIO | None) -> None:
        self.out = out
        self.live = out is not None and out.isatty()
        self._open = False

    def update(self, text: str) -> None:
        if self.out is None:
            return
        if self.live:
            self.out.write("\r" + text.ljust(80))
            self._open = True
        else:
            self.out.write(text + "\n")
        self.out.flush()

    def line(self, text: str) -> None:
        """A line of its own (a final status, an error)."""
        if self.out is None:
            return
        self.end()
        self.out.write(text + "\n")
        self.out.flush()

    def end(self) -> None:
        if self._open and self.out is not None:
            self.out.write("\n")
            self.out.flush()
        self._open = False


class FrameMemory:
    """The frames awaiting their results, by timestamp (bounded: dropped frames never get one).

    Frames pile up only while the netapp is slower than the source: then the frame before the newest is waiting for
    a slot, and the newest supersedes it (newest wins), so that one goes, never the oldest: those are in flight, and
    their results are on their way (a netapp taking seconds a frame once lost every frame of `--save` to them).
    An answered frame takes the older ones left with it: they were superseded, or answered already."""

    def __init__(self, capacity: int) -> None:
        self._frames: OrderedDict[int, SourceFrame] = OrderedDict()
        self.capacity = max(2, capacity)

    def keep(self, timestamp: int, frame: SourceFrame) -> None:
        self._frames[timestamp] = frame
        if len(self._frames) > self.capacity:
            superseded = list(self._frames)[-2]
            del self._frames[superseded]

    def take(self, timestamp: int) -> SourceFrame | None:
        frame = self._frames.pop(timestamp, None)
        if frame is not None:
            while self._frames and next(iter(self._frames)) < timestamp:
                self._frames.popitem(last=False)
        return frame


def stream(
    client: NetAppClient,
    frames: Iterable[np.ndarray | SourceFrame],
    fps: float,
    duration_s: float,
    progress: TextIO | Progress | None = None,
    drain_s: float = 5.0,
    sinks: Sequence[Sink] = (),
    lockstep: bool = False,
) -> dict[str, Any]:
    """Send `frames` for `duration_s`, then wait up to `drain_s` for the last results; the summary.

    A frame with a timeline (`SourceFrame.offset_s`, a recording) goes at its time; any other at `fps`; with
    `lockstep` each goes once the frames before it are answered (as fast as the netapp answers, none dropped).
    Each result carries its frame's stamp (`Result.source_stamp_ns`) and goes, with its frame, to every sink.
    """
    status = progress if isinstance(progress, Progress) else Progress(progress)
    period = 1.0 / fps
    every = 0.5 if status.live else 2.0  # a log file gets a line every 2 s, a terminal one line rewritten in place
    memory = FrameMemory(4 * client.max_in_flight + 8)
    keep_frames = any(s.needs_frames for s in sinks)
    last_output: dict[str, Any] = {}

    def drain() -> None:
        for result in client.results(timeout=0):
            frame = memory.take(result.timestamp)
            if frame is not None:
                result.source_stamp_ns = frame.stamp_ns
                result.frame_index = frame.index
            output = processor_output(result.message)
            if output:
                last_output.clear()
                last_output.update(output)
            for sink in sinks:
                sink.add(frame if keep_frames else None, result)

    start = time.monotonic()
    next_progress = start + every
    index = 0
    for item in frames:
        frame = item if isinstance(item, SourceFrame) else SourceFrame.captured(item)
        if frame.offset_s is not None and not lockstep:
            _sleep_until(start + frame.offset_s)
        now = time.monotonic()
        if now - start >= duration_s:
            break
        frame.index = index
        timestamp = client.send(frame.wire(as_recorded=client.options.sending.full_frames))
        memory.keep(timestamp, frame)
        index += 1
        drain()
        if now >= next_progress:
            status.update(progress_line(now - start, client.stats))
            next_progress = now + every
        if lockstep:
            client.wait_idle(drain_s)
        elif frame.offset_s is None:
            _sleep_until(start + index * period)
    elapsed = time.monotonic() - start
    client.wait_idle(drain_s)
    drain()
    status.line(progress_line(elapsed, client.stats))
    summary = client.stats.summary(elapsed)
    if last_output:
        summary["outputs"] = _shorten(last_output)
    return summary


def _sleep_until(due: float) -> None:
    delay = due - time.monotonic()
    if delay > 0:
        time.sleep(delay)  # pacing the frame rate, not synchronisation


def _shorten(output: dict[str, Any], limit: int = 300) -> str:
    text = json.dumps(output, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def open_sinks(args: argparse.Namespace, stack: contextlib.ExitStack) -> list[Sink]:
    sinks: list[Sink] = []
    if getattr(args, "show", False):
        sinks.append(Window())
    if getattr(args, "save", None):
        sinks.append(AnnotatedVideo(args.save, args.fps))
    if getattr(args, "jsonl", None):
        sinks.append(JsonLines(args.jsonl))
    if getattr(args, "mcap", None):
        from netapp.ros.recorder import McapRecorder

        sinks.append(McapRecorder(args.mcap))
    for sink in sinks:
        stack.callback(sink.close)
    return sinks


def stream_from_args(args: argparse.Namespace) -> int:
    size = parse_size(args.size)
    progress = Progress(None if args.json else sys.stderr)
    recording = None
    try:
        with contextlib.ExitStack() as stack:
            frames, recording = open_frames(args, size)
            if recording is not None:
                stack.callback(recording.close)
            duration = args.duration if args.duration is not None else (math.inf if recording else DEFAULT_DURATION_S)
            sinks = open_sinks(args, stack)
            client = stack.enter_context(_client_for(args, stack, progress))
            info = client.processor_info()
            lockstep = recording is not None and args.rate == 0
            summary = stream(client, frames, args.fps, duration, progress, sinks=sinks, lockstep=lockstep)
            counters = client.transport_report()  # before the client closes its sessions
    except USER_ERRORS as exc:
        progress.end()
        print(f"error: {exc}", file=sys.stderr)
        return 1
    summary.update(
        transport=args.transport,
        codec=client.codec,
        fps=args.fps,
        url=client.url,
        urls=list(client.urls),
        policy=args.policy,
        deadline_ms=args.deadline_ms,
        link_state=client.link_state,
    )
    if recording is not None:
        summary["recording"] = recording.report()
    adapt = client.adapt_report()
    if adapt is not None:
        summary["adapt"] = adapt
    if counters:
        summary["transport_counters"] = counters
    if info:
        summary["processor"] = " ".join(str(info[k]) for k in ("name", "platform", "provider") if info.get(k))
    print(json.dumps(summary) if args.json else format_summary(summary))
    if summary["results"] == 0:
        print(f"error: {no_results_line(summary)}", file=sys.stderr)
        return 1
    return 0


def open_frames(args: argparse.Namespace, size: tuple[int, int] | None) -> tuple[Iterable[Any], Any]:
    """The frames of `--source`, and the recording they come from (None for a video, an image or a camera)."""
    from netapp.ros.bags import BagSource, is_recording

    if is_recording(args.source):
        if args.rate < 0:
            raise SourceError(f"--rate must be 0 or more, got {args.rate:g}")
        recording = BagSource(args.source, args.topic, args.rate, size)
        return recording, recording
    if args.topic:
        raise SourceError(f"--topic is for a recording (a bag folder, .mcap or .bag), not {args.source}")
    return open_source(args.source, args.fps, size), None


def _fallback(model: str | None) -> Any:
    """The local fallback for `--fallback-model`: the netapp's detector on this machine (onnxruntime only then)."""
    if not model:
        return None
    if not os.path.isfile(model):
        raise NetAppError(f"--fallback-model {model}: no such file (give the path of an ONNX model, e.g. YOLOX-Nano)")
    from netapp.models import Detector, DetectorConfig

    return Detector(DetectorConfig(model))


def _webrtc_client(args: argparse.Namespace) -> Any:
    """`--transport webrtc`: one netapp, a peer of its own (`netapp.client.webrtc`)."""
    from netapp.client.webrtc import WebRtcClient
    from netapp.webrtc_ice import parse_ice_server

    if args.middleware or len(args.url) != 1:
        raise NetAppError("--transport webrtc streams to one netapp URL (no --middleware, no second URL)")
    try:
        servers = tuple(parse_ice_server(url) for url in args.ice_server)
    except ValueError as exc:
        raise NetAppError(str(exc)) from None
    return WebRtcClient(
        args.url[0],
        token=args.token or os.environ.get(TOKEN_ENV) or None,
        robot_id=args.robot_id,
        ice_servers=servers,
        ice_addresses=tuple(args.ice_address),
        max_in_flight=args.max_in_flight,
    )


def parse_size(text: str | None) -> tuple[int, int] | None:
    if not text:
        return None
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise SystemExit(f"--size must look like 640x480, got {text!r}") from None
    return width, height


def _client_for(args: argparse.Namespace, stack: contextlib.ExitStack, progress: Progress) -> NetAppClient:
    if args.transport == WEBRTC_TRANSPORT:
        return _webrtc_client(args)
    kwargs = dict(
        transport=args.transport,
        codec=args.codec,
        robot_id=args.robot_id,
        max_in_flight=args.max_in_flight,
        policy=args.policy,
        deadline_ms=args.deadline_ms,
        **sending_options(args),
        fallback=_fallback(args.fallback_model),
        on_switch=lambda s: progress.line(f"{s.state}: {s.reason}"),  # what the client does, as it changes
    )
    if not args.middleware:
        if not args.url:
            raise NetAppError("give the netapp URL, or --middleware URL to have one deployed")
        return NetAppClient(args.url, token=args.token or os.environ.get(TOKEN_ENV) or None, **kwargs)
    from netapp.client.middleware import MiddlewareClient

    secret = args.secret or os.environ.get("NETAPP_ROBOT_SECRET")
    if not (args.robot_id and secret):
        raise NetAppError("--middleware needs --robot-id and --secret (or NETAPP_ROBOT_SECRET)")

    def show(status: dict[str, Any]) -> None:
        progress.update(f"deployment {status.get('status')}: {status.get('message') or ''}")

    middleware = stack.enter_context(MiddlewareClient(args.middleware, args.robot_id, secret))
    endpoint = middleware.deploy(args.app, placement=args.placement, on_progress=show)
    progress.line(f"deployed {args.app} on {endpoint.pool}: {endpoint.url}")
    return middleware.netapp_client(endpoint, **kwargs)
