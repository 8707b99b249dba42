"""A NetApp's model changes in the catalogue: its running netapps try the new one as a rollout, not a restart.

Each tick reads the catalogue and asks the planner the operator asks too (netapp_operator.rollout_plan) what to do
with each live NetApp; this keeps only the I/O. A Ready NetApp whose app now names another model than the one it
serves (`spec.model` changed, or a `spec.rollout.candidate` named) gets `backend.rollout`: the candidate is shadowed
on the running netapp and promoted or rolled back there (docs/rollouts.md). Its progress is followed on the netapp
until the verdict, which is announced once (an Event; one log line on the local backend) and kept for `GET
/apps/{app}/rollouts`. A model is tried once whatever its verdict: after a rollback the netapp serves on the model
it had, until the catalogue names another. A rollout the netapp refuses (a judging value out of range, a rollout of
its own under way) is said once and tried again when the app's entry changes.

Only a backend with `rollout` and `rollout_state` (the local one) takes part; on Kubernetes the operator does this
for the NetApp objects.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
from collections.abc import Callable
from typing import Any

from netapp_operator.rollout_plan import (
    FOLLOW,
    PENDING,
    PROMOTED,
    REFUSED,
    RUNNING,
    START,
    Attempt,
    announce_now,
    next_step,
    stage_of,
)

from .backends.base import READY
from .catalogue import Catalogue
from .deployments import Registry
from .instances import Instance
from .rollouts import ModelKey, candidate_key, outcome_event, rollout_request, rollout_summary
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
        self._states: dict[str, dict[str, Any]] = {}  # NetApp name -> its latest rollout, as the API shows it
        self._attempts: dict[str, Attempt] = {}  # NetApp name -> what the planner reads of its latest rollout
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
        """Each live NetApp: what the planner says (netapp_operator.rollout_plan.next_step), done."""
        catalogue = await asyncio.to_thread(self.catalogue)  # a source may read a file
        live = {i.name: i for i in self.registry.instances()}
        for gone in set(self._attempts) - set(live):
            self._states.pop(gone, None)
            self._attempts.pop(gone, None)
        for instance in live.values():
            app = catalogue.get(instance.app)
            wanted = candidate_key(app.spec) if app is not None else None
            request = rollout_request(app.spec) if app is not None and wanted is not None else None
            last = self._attempts.get(instance.name)
            step = next_step(wanted, instance.model_key, instance.state.phase == READY, last, request)
            if step == START and app is not None and wanted is not None:
                await self._start(instance, app.spec, wanted, request)
            elif step == FOLLOW and last is not None:
                await self._follow(instance, last)

    async def _start(self, instance: Instance, spec: dict[str, Any], wanted: ModelKey, request: Any) -> None:
        try:
            state = await self.registry.backend.rollout(instance.name, spec)  # type: ignore[attr-defined]
        except ValueError as exc:  # e.g. a judging value the netapp refuses (422): said once, tried again when changed
            refused = Attempt(wanted, REFUSED, request=request)
            await self._record(instance, None, refused, {"phase": REFUSED, "model": wanted[0], "reason": str(exc)})
            return
        stage = stage_of(state.get("phase"))
        started = Attempt(wanted, RUNNING if stage == PENDING else stage, on=instance.name, request=request)
        await self._record(instance, None, started, state)

    async def _follow(self, instance: Instance, last: Attempt) -> None:
        try:
            state = await self.registry.backend.rollout_state(instance.name)  # type: ignore[attr-defined]
        except ValueError as exc:  # not answering this time: the next tick asks again
            log.debug("NetApp %s: its rollout state: %s", instance.name, exc)
            return
        if state is not None:  # a netapp that no longer runs it (restarted): PENDING, started again
            now = dataclasses.replace(last, stage=stage_of(state.get("phase")))
            await self._record(instance, last.stage, now, state)

    async def _record(self, instance: Instance, before: str | None, now: Attempt, state: dict[str, Any]) -> None:
        """Keep `state` for the API and `now` for the planner; a promoted model is what the netapp serves; a verdict
        is announced once."""
        self._states[instance.name] = {"netapp": instance.name, "app": instance.app, **rollout_summary(state)}
        self._attempts[instance.name] = now
        if now.stage == PROMOTED:
            instance.model_key = now.target
        event = outcome_event(instance.app, state)
        if event is not None and announce_now(before, now.stage):
            await self.registry.backend.announce(instance.name, *event)
