"""The one message a result becomes on a broker (docs/broker.md#the-message; its JSON Schema is
docs/broker/result.schema.json and its AsyncAPI document docs/broker/asyncapi.yaml): the result exactly as the robot
gets it, wrapped with who made it, from what, and when. Pure."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from netapp import wire_json

SCHEMA = "netapp.result/1"  # a message's `schema`: bumped on any change a reader must know of
CONTENT_TYPE = "application/json"


@dataclass(frozen=True)
class ModelIdentity:
    """The model that made a result: its name and, where the netapp has its file, the file's sha256."""

    name: str
    sha256: str | None = None


def result_message(
    result: dict[str, Any],
    *,
    netapp: str,
    source: str,
    session_id: str,
    model: ModelIdentity,
    published_ns: int | None = None,
) -> dict[str, Any]:
    """The broker message for one result. `source`: the robot's id (its session's id when it gave none) or the
    camera's name; `result`: the 5G-ERA result message (its `timestamp` is the frame's capture time, as the robot or
    camera stamped it, and its `recv_timestamp` / `send_timestamp` the netapp's monotonic clock around it)."""
    received, sent = result.get("recv_timestamp"), result.get("send_timestamp")
    latency_ms = (sent - received) / 1e6 if isinstance(received, int) and isinstance(sent, int) else None
    return {
        "schema": SCHEMA,
        # unique per frame, the same on every redelivery: what a reader deduplicates by (delivery is at least once)
        "id": f"{netapp}/{session_id}/{result.get('timestamp')}",
        "netapp": netapp,
        "source": source,
        "model": {"name": model.name, "sha256": model.sha256},
        "capture_ns": result.get("timestamp"),
        "latency_ms": latency_ms,  # in the netapp: the frame's receipt to its result leaving
        "published_ns": time.time_ns() if published_ns is None else published_ns,
        "result": result,
    }


def encode(message: dict[str, Any]) -> bytes:
    """JSON, as results are on every other transport (`netapp.wire_json`: NaN as null, numpy as numbers)."""
    return wire_json.dumpb(message)
