"""A frame on its way through the pipeline, and where what becomes of it goes: its waiter (HTTP `?wait=true`), its
sink (a push transport) or, with neither, the session's polled results."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from netapp.server.errors import FrameError
from netapp.server.sessions import Session


class ResultSink(Protocol):
    """Where a push transport sends what became of a frame (Socket.IO, frames, WebRTC: to the robot's connection; a
    camera: to its subscribers; RTP: to the transport that opened it). Each `Connection` names its own."""

    async def result(self, session: Session, message: dict[str, Any]) -> None: ...

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None: ...


@dataclass(frozen=True, slots=True)
class FrameTrace:
    """A frame sampled for tracing (`netapp.server.pipeline.tracing`): its trace, the netapp's frame span and that
    span's parent (0: none, the span is a root) with the parent's tracestate."""

    trace_id: int
    span_id: int
    parent_id: int = 0
    tracestate: str = ""


@dataclass(eq=False)  # a frame is itself: compared by identity (its prepared data may be an array)
class Frame:
    timestamp: int
    recv_ns: int
    seq: int
    transport: str  # the `transport` label of its metrics
    prepared: Any = None
    decode: Callable[[], Any] | None = None  # still to decode and prepare, on the inference thread
    waiter: asyncio.Future | None = None  # HTTP ?wait=true
    sink: ResultSink | None = None  # push transports; neither waiter nor sink: kept for polling
    image: np.ndarray | None = None  # the decoded frame, kept only while an observer watches its robot
    answered: bool = False  # its result or error went out
    superseded: bool = False  # a newer frame of its robot took its place before it was prepared
    deadline_ms: float | None = None  # the robot's: its result must leave by recv_ns + deadline_ms
    turn_ns: int = 0  # when its batch began on an inference thread (its decoding there included): its turn
    trace: FrameTrace | None = None  # sampled for tracing (`netapp.server.pipeline.tracing`); None: not traced
    decoded_ns: tuple[int, int] = (0, 0)  # a traced frame's decoding, start and end (monotonic ns)
    processor: Any = None  # the processor that prepared it and runs it (None: the current one)
    shadow_image: np.ndarray | None = None  # its picture, for a rollout's candidate that prepares its own input

    def cannot_finish(self, now_ns: int, expected_ns: float) -> bool:
        """Would its result leave after its deadline if processing started now and took `expected_ns`?"""
        return self.deadline_ms is not None and now_ns + expected_ns > self.recv_ns + self.deadline_ms * 1e6


def resolve(waiter: asyncio.Future | None, result: Any = None, exc: BaseException | None = None) -> None:
    """Answer a frame's waiter (HTTP ?wait=true), unless it has none or it was answered already."""
    if waiter is None or waiter.done():
        return
    if exc is not None:
        waiter.set_exception(exc)
    else:
        waiter.set_result(result)
