"""A NetApp's model changes in the catalogue: its running netapps try the new one as a rollout, not a restart.

Each tick reads the catalogue. A Ready NetApp whose app now names another model than the one it was started with
(`spec.model` changed, or a `spec.rollout.candidate` named) gets `backend.rollout`: the candidate is shadowed on the
running netapp and promoted or rolled back there (docs/rollouts.md). Its progress is followed on the netapp until
the verdict, which is announced once (an Event; one log line on the local backend) and kept for `GET
/apps/{app}/rollouts`. A model is tried once per change whatever its verdict: after a rollback the netapp serves on
the model it had, until the catalogue names another. A rollout the netapp refuses (a judging value out of range, a
rollout of its own under way) is said once and tried again when the app's entry changes.

Only a backend with `rollout` and `rollout_state` (the local one) takes part; on Kubernetes the operator does this
for the NetApp objects.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Any

from .backends.base import READY
from .catalogue import Catalogue
from .deployments import Registry
from .instances import Instance
from .rollouts import (
    PROMOTED,
    REFUSED,
    ROLLED_BACK,
    ModelKey,
    candidate_key,
    outcome_event,
    rollout_request,
    rollout_summary,
)
from .switchover.following import CATALOGUE_EVERY_S

log = logging.getLogger(__name__)


class ModelRollouts:
    """Starts and follows the rollouts the catalogue's changes call for; see the module docstring."""

    def __init__(
        self, registry: Registry, catalogue: Callable[[], Catalogue], every_s: float = CATALOGUE_EVERY_S
    ) -> None:
        self.registry = registry
        self.catalogue = catalogue
        self.every_s = every_s
        self._states: dict[str, dict[str, Any]] = {}  # NetApp name -> its latest rollout (live NetApps only)
        self._following: set[str] = set()  # NetApps whose rollout has no verdict yet
        self._refused: dict[str, dict[str, Any]] = {}  # NetApp name -> the rollout request it refused last
        self._task: asyncio.Task[None] | None = None

    @property
    def enabled(self) -> bool:
        backend = self.registry.backend
        return callable(getattr(backend, "rollout", None)) and callable(getattr(backend, "rollout_state", None))

    def start(self) -> None:
        if self.enabled and self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run())

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None

    def of_app(self, app: str) -> list[dict[str, Any]]:
        """The rollouts of `app`'s NetApps, by NetApp name."""
        states = list(self._states.values())  # one step: the API reads this from its threads
        return sorted((s for s in states if s["app"] == app), key=lambda s: s["netapp"])

    async def _run(self) -> None:
        while True:
            try:
                await self.tick()
            except Exception:  # one bad tick must not stop the next
                log.exception("model rollouts: a tick failed")
            await asyncio.sleep(self.every_s)

    async def tick(self) -> None:
        catalogue = await asyncio.to_thread(self.catalogue)  # a source may read a file
        live = {i.name: i for i in self.registry.instances()}
        for gone in set(self._states) - set(live):
            self._states.pop(gone, None)
            self._following.discard(gone)
            self._refused.pop(gone, None)
        for instance in live.values():
            if instance.name in self._following:
                await self._follow(instance)
                continue
            app = catalogue.get(instance.app)
            wanted = candidate_key(app.spec) if app is not None else None
            if wanted is None or instance.model_key in (None, wanted) or instance.state.phase != READY:
                continue
            if self._refused.get(instance.name) != rollout_request(app.spec):  # refused as it is: wait for a change
                await self._start(instance, app.spec, wanted)

    async def _start(self, instance: Instance, spec: dict[str, Any], wanted: ModelKey) -> None:
        try:
            state = await self.registry.backend.rollout(instance.name, spec)  # type: ignore[attr-defined]
        except ValueError as exc:  # e.g. a judging value the netapp refuses (422): said once, tried again when changed
            self._refused[instance.name] = rollout_request(spec)
            await self._record(instance, {"phase": REFUSED, "model": wanted[0], "reason": str(exc)})
            return
        instance.model_key = wanted  # tried once, whatever its verdict
        self._refused.pop(instance.name, None)
        self._following.add(instance.name)
        await self._record(instance, state)

    async def _follow(self, instance: Instance) -> None:
        try:
            state = await self.registry.backend.rollout_state(instance.name)  # type: ignore[attr-defined]
        except ValueError as exc:  # not answering this time: the next tick asks again
            log.debug("NetApp %s: its rollout state: %s", instance.name, exc)
            return
        if state is not None:
            await self._record(instance, state)

    async def _record(self, instance: Instance, state: dict[str, Any]) -> None:
        """Keep `state` for the API; on a verdict, stop following and announce it (once)."""
        self._states[instance.name] = {"netapp": instance.name, "app": instance.app, **rollout_summary(state)}
        if state.get("phase") in (PROMOTED, ROLLED_BACK, REFUSED):
            self._following.discard(instance.name)
            event = outcome_event(instance.app, state)
            if event is not None:
                await self.registry.backend.announce(instance.name, *event)
