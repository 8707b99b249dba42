"""The operator's side of a model rollout (I/O, docs/rollouts.md#kubernetes): what to do next is the planner's
(`rollouts.next_step`, over netapp_operator.rollout_plan, which the middleware's driver asks too); this starts it
on one ready pod of the NetApp (`POST /rollout` with the operator's token), asks that pod how it goes (`GET
/rollout`) every few seconds, and writes `status.rollout`, `status.model` on promotion and an Event at the verdict
(the reconcile writes the ModelRollout condition from `status.rollout`).

Every request is bounded (`rollout_timeout_seconds`) and nothing a netapp answers, nor a netapp that does not
answer, raises out of `tick`: it shows in `status.rollout.reason` and the next tick tries again.
"""

from __future__ import annotations

import asyncio
import datetime
import json
import logging
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

import aiohttp

from netapp_operator import render, rollout_plan, rollout_status, rollouts
from netapp_operator.cache import Key
from netapp_operator.config import OperatorConfig
from netapp_operator.kube import Kube
from netapp_operator.rollout_plan import stage_of
from netapp_operator.spec import parse
from netapp_operator.status import timestamp

logger = logging.getLogger(__name__)
MAX_ANSWER_BYTES = 64 * 1024  # GET /rollout's JSON is about 1 KiB: a netapp that sends more is not read further
Announce = Callable[[Mapping[str, Any], str, str, str], Awaitable[None]]  # (object, type, reason, message)


def utcnow() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc)


class NetAppAnswer(Exception):
    """A netapp's answer the rollout cannot go on with, as one line for `status.rollout.reason`."""


class RolloutPoller:
    def __init__(self, kube: Kube, config: OperatorConfig, announce: Announce) -> None:
        self.kube = kube
        self.config = config
        self.announce = announce
        self._last: dict[Key, dict[str, Any]] = {}  # what was written last: a tick before its watch event
        self._session: aiohttp.ClientSession | None = None

    def wanted(self, body: Mapping[str, Any]) -> dict[str, Any] | None:
        cfg = self.config
        return rollouts.wanted_model(body.get("spec") or {}, cfg.default_model_url, cfg.default_model_sha256)

    def active(self, body: Mapping[str, Any]) -> bool:
        """Whether the NetApp has a rollout to start or under way."""
        return rollouts.active(body, self.wanted(body))

    def forget_others(self, netapps: list[Mapping[str, Any]]) -> None:
        """Drop what was written of the NetApps not in `netapps` (deleted, or their rollout over)."""
        keep = {(n["metadata"].get("namespace"), n["metadata"]["name"]) for n in netapps}
        for key in [k for k in self._last if k not in keep]:
            del self._last[key]

    async def close(self) -> None:
        if self._session is not None:
            await self._session.close()

    async def tick(self, body: Mapping[str, Any]) -> None:
        """One step of the NetApp's rollout: start it, or read how it goes; status written when it changed."""
        meta = body["metadata"]
        key = (meta.get("namespace"), meta["name"])
        wanted = self.wanted(body)
        if not rollouts.active(body, wanted):  # as the NetApp's status says
            self._last.pop(key, None)
            return
        # what was written last, which its watch event may not have brought yet
        old = self._last.get(key) or dict((body.get("status") or {}).get("rollout") or {})
        step = rollouts.next_step(body, wanted, old)
        if step == rollout_plan.LEAVE:
            return  # written already; its watch event is on the way
        assert wanted is not None  # a rollout to start has a target
        now = utcnow()
        try:
            new = await (self._start(body, wanted, now) if step == rollout_plan.START else self._poll(body, old, now))
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # an API server error, a netapp's nonsense: shown, tried again next tick
            logger.warning("rollout of NetApp %s/%s: %s", key[0], key[1], exc)
            base = old if step == rollout_plan.FOLLOW else rollout_status.pending(wanted, "", now)
            new = {**base, "reason": str(exc)[:300] or type(exc).__name__, "updatedAt": timestamp(now)}
        await self._write(body, key, old, new)

    async def _start(self, body: Mapping[str, Any], wanted: Mapping[str, Any], now: datetime.datetime) -> dict:
        meta = body["metadata"]
        spec = parse(body.get("spec"))
        pool = (body.get("status") or {})["pool"]
        labels = render.labels(meta["name"], pool)
        pod = rollouts.ready_pod(await self.kube.list("Pod", meta["namespace"], labels), labels)
        if pod is None:
            deployment = render.child_name(meta["name"], pool)
            return rollout_status.pending(wanted, f"waiting for a ready pod of Deployment {deployment}", now)
        name = pod["metadata"]["name"]
        url = rollouts.pod_url(pod, int(spec.port), spec.tls is not None)
        request = rollouts.rollout_request(body.get("spec") or {})
        code, answer = await self._call("POST", url, name, request)
        if code == 409:  # one runs already: ours, when a restarted operator started it and never wrote it down
            code, answer = await self._call("GET", url, name)
            if answer.get("model") != wanted["url"] or answer.get("phase") not in ("shadow", "canary"):
                raise NetAppAnswer(f"pod {name} runs another rollout ({answer.get('model')}): waiting for its end")
        elif code != 202:
            detail = answer.get("detail") or answer.get("error") or answer
            raise NetAppAnswer(f"pod {name} refused the rollout (HTTP {code}): {str(detail)[:200]}")
        return rollout_status.started(wanted, name, now)

    async def _poll(self, body: Mapping[str, Any], old: Mapping[str, Any], now: datetime.datetime) -> dict:
        meta = body["metadata"]
        name = old["pod"]
        pod = await self.kube.get("Pod", meta["namespace"], name)
        if not rollouts.pod_ready(pod):
            target = old["target"]
            return rollout_status.pending(target, f"pod {name} went away before a verdict: trying another", now)
        assert pod is not None
        spec = parse(body.get("spec"))
        code, state = await self._call("GET", rollouts.pod_url(pod, int(spec.port), spec.tls is not None), name)
        if code != 200:
            raise NetAppAnswer(f"pod {name} answered GET /rollout with HTTP {code}")
        if state.get("phase") not in rollout_status.PHASES or state.get("model") != old["target"]["url"]:
            # its netapp restarted (no rollout), or another rollout replaced ours: start again
            return rollout_status.pending(old["target"], f"pod {name} no longer runs this rollout: starting again", now)
        return rollout_status.from_state(old, state, now)

    async def _call(self, method: str, url: str, pod: str, body: Any = None) -> tuple[int, dict[str, Any]]:
        """One bounded request to a pod's /rollout: (HTTP status, its JSON object or {})."""
        if self._session is None:
            timeout = aiohttp.ClientTimeout(total=self.config.rollout_timeout_seconds)
            self._session = aiohttp.ClientSession(timeout=timeout)
        headers = {"Authorization": f"Bearer {self.config.rollout_token}"}
        # A pod's certificate names its Service, not the pod's IP (which the API server gave): not verified.
        try:
            async with self._session.request(method, url + "/rollout", json=body, headers=headers, ssl=False) as r:
                raw = await r.content.read(MAX_ANSWER_BYTES + 1)
                code = r.status
        except (aiohttp.ClientError, asyncio.TimeoutError) as exc:
            raise NetAppAnswer(f"cannot reach pod {pod} at {url}: {exc or type(exc).__name__}") from None
        if len(raw) > MAX_ANSWER_BYTES:
            raise NetAppAnswer(f"pod {pod} answered {method} /rollout with more than {MAX_ANSWER_BYTES} bytes")
        try:
            answer = json.loads(raw) if raw else {}
        except ValueError:
            answer = {}
        return code, answer if isinstance(answer, dict) else {}

    async def _write(self, body: Mapping[str, Any], key: Key, old: Mapping[str, Any], new: dict[str, Any]) -> None:
        if rollout_status.same(old, new):
            return
        meta, status = body["metadata"], body.get("status") or {}
        served = status.get("model")
        promoted = new.get("phase") == "Promoted"
        # A merge patch: keys of the rollout before (another candidate's numbers) are removed, not merged. The
        # ModelRollout condition is the reconcile's to write (one writer of the conditions), from status.rollout.
        patch: dict[str, Any] = {"rollout": {**dict.fromkeys({*(status.get("rollout") or {}), *old}), **new}}
        if promoted:
            patch["model"] = dict(new["target"])  # the next reconcile renders it: the pods roll to it
        await self.kube.patch_status("NetApp", meta["namespace"], meta["name"], patch)
        self._last[key] = new
        event = rollout_status.announcement(new, served)
        if event is not None and rollout_plan.announce_now(stage_of(old.get("phase")), stage_of(new.get("phase"))):
            await self.announce(body, *event)
