"""The bodies of the netapp's HTTP API (what /openapi.json describes)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field


class RegisterRequest(BaseModel):
    robot_id: str | None = Field(default=None, max_length=256)
    args: dict[str, Any] = Field(default_factory=dict)


class RegisterResponse(BaseModel):
    session_id: str
    # [width, height] the processor consumes (None: any): a robot sends no larger frames (docs/server.md#input-size)
    input_size: list[int] | None = None
    # the accuracy profile its results follow (None: none known; docs/client.md#an-uplink-that-adapts)
    accuracy_profile: str | None = None
    # with `rtp` in args: the port, SSRC and SDP to send H.264 over RTP with (docs/cameras.md#rtp-push)
    rtp: dict[str, Any] | None = None


class SessionStats(BaseModel):
    session_id: str
    transport: str
    robot_id: str | None
    received: int
    processed: int
    dropped: int
    deadline_dropped: int
    rejected: int
    queue_depth: int


class PolledResults(BaseModel):
    results: list[dict[str, Any]]  # result messages, or {"timestamp", "error", "reason"} for a frame that failed
    dropped: int
    results_overflowed: int


class Queued(BaseModel):
    timestamp: int
    queued: bool = True


class Capacity(BaseModel):
    id: str | None
    name: str | None
    currentRobotsCount: int  # noqa: N815 (5G-ERA's field names)
    optimalLimit: int | None  # noqa: N815
    hardLimit: int | None  # noqa: N815
    capacity_fps: float | None
    demand_fps: float
    optimal: int | None
    hard: int | None
    measured: bool


class Health(BaseModel):
    status: str
