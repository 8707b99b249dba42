"""Which replica pulls which camera: one Kubernetes Lease (`coordination.k8s.io/v1`) per camera, as Kubernetes' own
controllers elect a leader, never an election of our own (docs/cameras.md#several-replicas).

The holder renews its Lease every RENEW_S; a Lease not renewed for LEASE_S is expired, and another replica takes it
(the Lease's resourceVersion is the patch's precondition, so of two replicas racing only one wins: the other gets
409). A replica that stops gives its Leases back at once, so another takes over within RENEW_S, not LEASE_S. The
decisions are pure (`decide`, `lease_manifest`); `CameraLeases` is the thin loop over the Kubernetes API.
"""

from __future__ import annotations

import asyncio
import datetime
import logging
from collections.abc import Callable, Mapping
from typing import Any, Protocol

log = logging.getLogger(__name__)

LEASE_S = 10  # a camera whose replica stopped renewing is taken over after this
RENEW_S = LEASE_S / 3
KIND = "Lease"
API_VERSION = "coordination.k8s.io/v1"
CREATE, RENEW, TAKE, WAIT = "create", "renew", "take", "wait"


def lease_name(prefix: str, camera: str) -> str:
    """The Lease of `camera` (a DNS subdomain: the names checked by `naming`, lower-cased)."""
    return f"{prefix}-camera-{camera}".lower().replace("_", "-")[:253]


def decide(lease: Mapping[str, Any] | None, me: str, now: datetime.datetime) -> str:
    """What this replica (`me`) does about a camera's Lease as read now: create it (none), renew it (ours), take it
    (expired, or given back), or wait (another replica holds it)."""
    if lease is None:
        return CREATE
    spec = lease.get("spec") or {}
    holder = spec.get("holderIdentity") or ""
    if holder == me:
        return RENEW
    if not holder:
        return TAKE
    renewed = _time(spec.get("renewTime") or spec.get("acquireTime"))
    duration = spec.get("leaseDurationSeconds")
    if renewed is None or not isinstance(duration, int) or renewed + datetime.timedelta(seconds=duration) < now:
        return TAKE
    return WAIT


def lease_manifest(name: str, namespace: str, me: str, now: datetime.datetime, held_before: Any = None) -> dict:
    """The Lease `me` holds from `now` (`held_before`: the Lease it takes, whose transitions it counts)."""
    spec = (held_before or {}).get("spec") or {}
    transitions = spec.get("leaseTransitions") if isinstance(spec.get("leaseTransitions"), int) else 0
    return {
        "apiVersion": API_VERSION,
        "kind": KIND,
        "metadata": {"name": name, "namespace": namespace},
        "spec": {
            "holderIdentity": me,
            "leaseDurationSeconds": LEASE_S,
            "acquireTime": _stamp(now),
            "renewTime": _stamp(now),
            "leaseTransitions": transitions + (1 if held_before is not None else 0),
        },
    }


def _stamp(t: datetime.datetime) -> str:
    """A MicroTime, as the API server writes it."""
    return t.astimezone(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _time(value: Any) -> datetime.datetime | None:
    if not isinstance(value, str):
        return None
    try:
        return datetime.datetime.fromisoformat(value.replace("Z", "+00:00"))
    except ValueError:
        return None


class LeaseApi(Protocol):
    """What the loop needs of a Kubernetes client (`netapp_operator.kube.Kube` is one)."""

    async def get(self, kind: str, namespace: str | None, name: str) -> dict[str, Any] | None: ...

    async def create(self, manifest: Mapping[str, Any]) -> dict[str, Any]: ...

    async def merge_patch(self, kind: str, namespace: str | None, name: str, patch: Mapping[str, Any]) -> Any: ...


class CameraLeases:
    """Holds the Leases of the cameras it can, tells `changed(camera, held)` when one is won or lost."""

    def __init__(
        self, api: LeaseApi, namespace: str, prefix: str, me: str, changed: Callable[[str, bool], None]
    ) -> None:
        self.api, self.namespace, self.prefix, self.me, self.changed = api, namespace, prefix, me, changed
        self.held: dict[str, bool] = {}
        self.holders: dict[str, str] = {}  # each camera's holder as last read ("": nobody): a WATCH is relayed from it
        self.failing: set[str] = set()  # cameras whose last round failed (told once)

    async def run(self, cameras: list[str]) -> None:
        """Claim and renew until cancelled; an API error counts as not holding (another replica may take over)."""
        for camera in cameras:
            self.held[camera] = False
        while True:
            for camera in cameras:
                try:
                    held = await self.claim(camera)
                    self.failing.discard(camera)
                except asyncio.CancelledError:
                    raise
                except Exception as exc:  # the API server away, RBAC missing: said once, until a round works
                    if camera not in self.failing:
                        log.warning(
                            "camera %s: its Lease could not be read or written (%s); not pulling it", camera, exc
                        )
                        self.failing.add(camera)
                    held = False
                    self.holders.pop(camera, None)
                if held != self.held[camera]:
                    self.held[camera] = held
                    self.changed(camera, held)
            await asyncio.sleep(RENEW_S)  # the renewal period itself

    async def claim(self, camera: str) -> bool:
        """One round for one camera: whether this replica holds its Lease now."""
        name = lease_name(self.prefix, camera)
        lease = await self.api.get(KIND, self.namespace, name)
        now = datetime.datetime.now(datetime.timezone.utc)
        action = decide(lease, self.me, now)
        if action == WAIT:
            holder = ((lease or {}).get("spec") or {}).get("holderIdentity")
            self.holders[camera] = holder if isinstance(holder, str) else ""
            return False
        if action == CREATE:
            try:
                await self.api.create(lease_manifest(name, self.namespace, self.me, now))
            except Exception as exc:
                if getattr(exc, "status", None) == 409:  # another replica created it first
                    return False
                raise
            self.holders[camera] = self.me
            return True
        spec: dict[str, Any] = {"renewTime": _stamp(now)}
        if action == TAKE:
            spec = lease_manifest(name, self.namespace, self.me, now, lease)["spec"]
        patch = {"metadata": {"resourceVersion": lease["metadata"].get("resourceVersion")}, "spec": spec}
        try:
            await self.api.merge_patch(KIND, self.namespace, name, patch)
        except Exception as exc:
            if getattr(exc, "status", None) == 409:  # changed since read: another replica won the race
                return False
            raise
        self.holders[camera] = self.me
        return True

    async def release(self) -> None:
        """Give back the Leases held, so another replica takes the cameras over at its next round."""
        for camera, held in self.held.items():
            if held:
                name = lease_name(self.prefix, camera)
                try:
                    await self.api.merge_patch(KIND, self.namespace, name, {"spec": {"holderIdentity": ""}})
                except Exception as exc:  # it expires anyway
                    log.warning("camera %s: could not give its Lease back (%s)", camera, exc)
                self.held[camera] = False
