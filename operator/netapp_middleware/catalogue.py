"""The catalogue of deployable apps: name -> a NetApp spec template (and an optional 5G-ERA task id).

A catalogue document (YAML, from a file or a ConfigMap key) is a map, optionally under ``apps:``::

    object-detection:
      description: YOLOX-Nano object detection (COCO, 80 classes)
      taskId: ca5b6bd9-dab0-5890-8738-12d7a68490e6   # what a 5G-ERA robot sends as TaskId
      spec: {image: ..., processor: ..., port: 5896, model: {url: ..., sha256: ...}, ...}   # a NetApp spec
      standby: nextBest   # optional: keep a warm netapp on its robots' next-best placement (or name a placement)
      channel: {broker: kafka://kafka:9092/}   # optional: robots send frames through this broker (channel.py)

A spec may name the facility's cameras (`sources: [{name, url}]`, docs/cameras.md): the catalogue names them, never a
robot's request, so no robot can make a netapp connect where it likes.
"""

from __future__ import annotations

import copy
import re
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from netapp_operator.constants import DEFAULT_MODEL_SHA256, DEFAULT_MODEL_URL, NETAPP_IMAGE, NETAPP_PORT

from .channel import BrokerChannel, parse_channel

# uuid5(NAMESPACE_URL, "netapp-toolkit:<app name>"): stable, so 5G-ERA robot configurations can hard-code them.
OBJECT_DETECTION_TASK_ID = "ca5b6bd9-dab0-5890-8738-12d7a68490e6"
OBJECT_TRACKING_TASK_ID = "33549b25-824b-5c93-81da-a3befa59a0b3"
PLACEMENT_POLICIES = ("edge", "cloud", "auto")
STANDBY_NEXT_BEST = "nextBest"  # `standby`: the next-best placement of each robot of the app
# edge, cloud, auto, or a node pool's (DNS-1123 label) name.
PLACEMENT_PATTERN = r"^[a-z0-9]([-a-z0-9]{0,61}[a-z0-9])?$"


def _yolox_spec(processor: str | None = None) -> dict[str, Any]:
    """A YOLOX-Nano app's spec: the built-in detector, or a built-in `processor` over it."""
    return {
        "image": NETAPP_IMAGE,
        **({"processor": processor} if processor else {}),
        "port": NETAPP_PORT,
        "model": {"url": DEFAULT_MODEL_URL, "sha256": DEFAULT_MODEL_SHA256, "timeoutSeconds": 300},
        "replicas": 1,
        "resources": {"cpu": "1", "memory": "1Gi"},
        "placement": {"policy": "auto"},
    }


DEFAULT_CATALOGUE: dict[str, Any] = {
    "object-detection": {
        "description": "YOLOX-Nano object detection (COCO, 80 classes) over the 5G-ERA protocol",
        "taskId": OBJECT_DETECTION_TASK_ID,
        "spec": _yolox_spec(),
    },
    "object-tracking": {
        "description": "YOLOX-Nano detection with ByteTrack: each detection keeps a track_id from frame to frame",
        "taskId": OBJECT_TRACKING_TASK_ID,
        "spec": _yolox_spec("object-tracking"),
    },
}


@dataclass(frozen=True)
class App:
    name: str
    spec: dict[str, Any]
    description: str = ""
    task_id: str | None = None
    # Unmodified 5G-ERA robots send no token, hence the default; False: each NetApp of this app needs its own token,
    # which the middleware hands to the robot with the URL.
    allow_unauthenticated: bool = True
    standby: str | None = None  # STANDBY_NEXT_BEST or a placement: a warm netapp waits there for its robots
    channel: BrokerChannel | None = None  # robots' frames through a broker (None: to the netapp's own URL)

    def public(self) -> dict[str, Any]:
        return {
            "description": self.description,
            "taskId": self.task_id,
            "spec": self.spec,
            "allowUnauthenticated": self.allow_unauthenticated,
            "standby": self.standby,
            "channel": self.channel.public() if self.channel else None,
        }


@dataclass(frozen=True)
class Catalogue:
    apps: dict[str, App] = field(default_factory=dict)

    def get(self, name: str) -> App | None:
        return self.apps.get(name)

    def by_task_id(self, task_id: str) -> App | None:
        wanted = task_id.lower()
        return next((app for app in self.apps.values() if app.task_id and app.task_id.lower() == wanted), None)


def parse_catalogue(data: Any) -> Catalogue:
    """Validate a catalogue document; raises ValueError with the offending app's name."""
    if isinstance(data, Mapping) and "apps" in data:
        data = data["apps"]
    if not isinstance(data, Mapping):
        raise ValueError("the catalogue must be a map of app name -> {spec, taskId?, description?}")
    apps: dict[str, App] = {}
    for name, entry in data.items():
        if not isinstance(entry, Mapping):
            raise ValueError(f"app {name!r}: needs a 'spec' map (a NetApp spec template)")
        spec = entry.get("spec")
        if not isinstance(spec, Mapping) or "image" not in spec:
            raise ValueError(f"app {name!r}: needs a spec (a NetApp spec template) with an 'image'")
        task_id = entry.get("taskId")
        if task_id is not None:
            try:
                task_id = str(uuid.UUID(str(task_id)))
            except ValueError as exc:
                raise ValueError(f"app {name!r}: taskId {task_id!r} is not a UUID") from exc
        open_access = entry.get("allowUnauthenticated", True)
        if not isinstance(open_access, bool):
            raise ValueError(f"app {name!r}: allowUnauthenticated must be true or false")
        standby = entry.get("standby")
        if standby is not None and not (
            standby == STANDBY_NEXT_BEST or (isinstance(standby, str) and re.match(PLACEMENT_PATTERN, standby))
        ):
            raise ValueError(f"app {name!r}: standby must be {STANDBY_NEXT_BEST} or a placement, got {standby!r}")
        apps[str(name)] = App(
            name=str(name),
            spec=dict(spec),
            description=str(entry.get("description", "")),
            task_id=task_id,
            allow_unauthenticated=open_access,
            standby=standby,
            channel=parse_channel(entry.get("channel"), str(name)),
        )
    return Catalogue(apps)


def placement_spec(template: Mapping[str, Any] | None, placement: str | None) -> dict[str, Any]:
    """The NetApp `spec.placement` for a robot's request: a policy name, or else a node pool name.

    The template's `requireGPU` survives a policy choice; no request keeps the template's own placement.
    """
    template = dict(template or {"policy": "auto"})
    if placement is None:
        return template
    if placement in PLACEMENT_POLICIES:
        out: dict[str, Any] = {"policy": placement}
        if "requireGPU" in template:
            out["requireGPU"] = template["requireGPU"]
        return out
    return {"pool": placement}


def render_spec(app: App, placement: str | None, netapp: str = "netapp") -> dict[str, Any]:
    """The NetApp spec to create for `app` placed as asked, named `netapp` (the template itself is never modified):
    an app whose channel is a broker consumes its robots' frames there."""
    spec = copy.deepcopy(app.spec)
    spec["placement"] = placement_spec(app.spec.get("placement"), placement)
    if app.channel is not None:
        spec["consume"] = [*(spec.get("consume") or []), app.channel.consume(netapp)]
    return spec
