"""A NetApp's model changes in the catalogue: its running netapps try the new one as a rollout, not a restart.

Each tick reads the catalogue and asks the planner the operator asks too (netapp_operator.rollout_plan) what to do
with each live NetApp; this keeps only the I/O. A Ready NetApp whose app now names another model than the one it
serves (`spec.model` changed, or a `spec.rollout.candidate` named) gets `backend.rollout`: the candidate is shadowed
on the running netapp and promoted or rolled back there (docs/rollouts.md). Its progress is followed on the netapp
until the verdict, which is announced once (an Event; one log line on the local backend) and kept for `GET
/apps/{app}/rollouts`. A model is tried once whatever its verdict: after a rollback the netapp serves on the model
it had, until the catalogue names another. A rollout the netapp refuses (a judging value out of range, a rollout of
its own under way) is said once and tried again when the app's entry changes.

A rollout's record outlives its netapp: when the netapp stops (its robots left, it slept, it exited, its NetApp was
deleted) with a rollout under way, the record keeps what was last seen and the phase `stopped`, its reason `no
verdict: stopped after N frames compared, agreement X, slowdown Y`, logged once (`ended`). The local backend reads
the rollout one last time just before it stops a netapp (`under_way`, `ended`: the backend's `rollout_sink`).

Only a backend with `rollout` and `rollout_state` (the local one) has its rollouts started here; on Kubernetes the
operator does this for the NetApp objects, and the backend's watch hands each NetApp's `status.rollout` to `observe`
and its deletion to `ended`, so the API shows those rollouts too, and their end.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from netapp_operator.rollout_plan import (
    FOLLOW,
    PENDING,
    PROMOTED,
    REFUSED,
    RUNNING,
    START,
    VERDICTS,
    Attempt,
    announce_now,
    next_step,
    stage_of,
)

from .backends.base import READY, RolloutRefused
from .catalogue import Catalogue
from .deployments import Registry
from .instances import Instance
from .rollouts import (
    STOPPED,
    ModelKey,
    candidate_key,
    final_record,
    outcome_event,
    rollout_request,
    rollout_summary,
    stopped_event,
)
from .switchover.following import CATALOGUE_EVERY_S

log = logging.getLogger(__name__)
ENDED_KEPT = 64  # the records of rollouts whose netapp is gone that the API still shows (the newest)


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
        self._ended: deque[str] = deque()  # NetApps whose netapp stopped, oldest first: their records are kept
        if hasattr(registry.backend, "rollout_sink"):  # it tells us when a netapp stops, or what its status says
            registry.backend.rollout_sink = self  # type: ignore[attr-defined]

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
        for gone in set(self._attempts) - set(live):  # deleted without the backend saying so first
            self.ended(gone)
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
        except RolloutRefused as exc:  # e.g. a judging value out of range (422): said once, tried again when changed
            refused = Attempt(wanted, REFUSED, request=request)
            await self._record(instance, None, refused, {"phase": REFUSED, "model": wanted[0], "reason": str(exc)})
            return
        except ValueError as exc:  # its netapp not there to ask (stopping, asleep): the next tick tries again
            log.debug("NetApp %s: rollout not started: %s", instance.name, exc)
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
        if state is None:  # its netapp no longer runs (it exited, or slept without the backend saying so)
            self.ended(instance.name)
        else:  # a netapp that no longer runs it (restarted): PENDING, started again
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

    # -- what a backend tells (its `rollout_sink`) -----------------------------------------------------------------

    def under_way(self, name: str) -> bool:
        """Whether NetApp `name` runs a rollout this follows (the local backend reads it once more before a stop)."""
        attempt = self._attempts.get(name)
        return attempt is not None and attempt.under_way

    def observe(self, name: str, app: str, state: dict[str, Any]) -> None:
        """NetApp `name`'s rollout as someone else drives it (the operator: its `status.rollout`, in the netapp's
        terms, `netapp_operator.rollout_status.as_netapp_state`), shown by the API like ours."""
        self._states[name] = {"netapp": name, "app": app, **rollout_summary(state)}

    def ended(self, name: str, state: dict[str, Any] | None = None) -> None:
        """NetApp `name`'s netapp stopped; `state`: its rollout as read just before (else what was seen last). The
        record keeps its verdict, or says there is none and what had been seen (`rollouts.final_record`), logged
        once. A rollout without a verdict is tried again if its netapp starts again (woken); one with a verdict
        is not."""
        attempt = self._attempts.get(name)
        if attempt is not None and attempt.stage not in VERDICTS:
            del self._attempts[name]
        kept = self._states.get(name)
        if kept is None or "stopped_at" in kept:  # nothing seen, or said already
            return
        before = stage_of(kept.get("phase"))
        if state is not None:
            kept = {**kept, **rollout_summary(state)}
        final = final_record(kept, time.time())
        self._states[name] = final
        if final["phase"] == STOPPED:
            type_, reason, message = stopped_event(final["app"], final)
        elif announce_now(before, stage_of(final["phase"])) and (event := outcome_event(final["app"], final)):
            type_, reason, message = event  # a verdict given just before it stopped: said here, its NetApp gone
        else:
            type_ = ""
        if type_:
            log.log(logging.WARNING if type_ == "Warning" else logging.INFO, "NetApp %s: %s: %s", name, reason, message)
        self._ended.append(name)
        while len(self._ended) > ENDED_KEPT:
            oldest = self._ended.popleft()
            if oldest not in self._attempts:  # not started again since
                self._states.pop(oldest, None)
