"""Kubernetes Events about an object (pure): one manifest for the operator's and the middleware's Events."""

from __future__ import annotations

import datetime
import uuid
from collections.abc import Mapping
from typing import Any

from netapp_operator.status import timestamp


def event_manifest(
    obj: Mapping[str, Any],
    type_: str,
    reason: str,
    message: str,
    *,
    component: str,
    instance: str,
    now: datetime.datetime | None = None,
) -> dict[str, Any]:
    """A core/v1 Event about `obj` (a Kubernetes object as read from the API), posted by `component`."""
    meta = obj["metadata"]
    stamp = timestamp(now or datetime.datetime.now(datetime.timezone.utc))
    return {
        "apiVersion": "v1",
        "kind": "Event",
        # An explicit unique name rather than generateName: cheaper for the server, works on emulators too.
        "metadata": {
            "name": f"{meta['name']}.{uuid.uuid4().hex[:16]}",
            "namespace": meta.get("namespace") or "default",
        },
        "involvedObject": {
            "apiVersion": obj.get("apiVersion", ""),
            "kind": obj.get("kind", ""),
            "name": meta["name"],
            "namespace": meta.get("namespace"),
            "uid": meta.get("uid"),
        },
        "type": type_,
        "reason": reason,
        "message": message[:1024],
        "source": {"component": component},
        "reportingComponent": component,
        "reportingInstance": instance,
        "firstTimestamp": stamp,
        "lastTimestamp": stamp,
        "count": 1,
    }
