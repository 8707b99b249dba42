"""A model rollout (docs/rollouts.md): its state (GET /rollout, open like /metrics), and starting one on the running
netapp (POST /rollout: an admin's, with the netapp's token or the replicas' cluster key)."""

from __future__ import annotations

import hmac
import json
from dataclasses import fields
from typing import Any

from fastapi import APIRouter, Header, Request

from netapp.http_errors import HTTPError
from netapp.server import access
from netapp.server.errors import FrameRejected
from netapp.server.http.body import read_limited
from netapp.server.http.dependencies import Services
from netapp.server.rollout.rollout import RolloutRefused
from netapp.server.services import NetAppServices
from netapp.server.settings import Policy, Shadowing

router = APIRouter()
MAX_BODY_BYTES = 4096  # a model's path or URL and a few numbers
BODY_TIMEOUT_S = 10.0
MAX_MODEL_CHARS = 2048


@router.get("/rollout")
async def rollout_state(services: Services) -> dict[str, Any]:
    """The rollout's phase (none, shadow, canary, promoted, rolled_back), its comparison so far and its reason."""
    return services.rollout.to_json()


@router.post("/rollout", status_code=202)
async def start_rollout(
    request: Request, services: Services, authorization: str | None = Header(default=None)
) -> dict[str, Any]:
    """Start a rollout of `candidate` (a model path on the netapp, or an http(s) URL) with the given judging."""
    try:
        check_admin(services, access.bearer(authorization))
        try:
            body = await read_limited(request, MAX_BODY_BYTES, BODY_TIMEOUT_S, "rollout request")
        except FrameRejected as exc:
            raise HTTPError(exc.status, exc.reason, str(exc)) from None
        model, sha256, policy, shadowing = parse_request(body)
        try:
            services.rollout.start(model, sha256, policy, shadowing)
        except RolloutRefused as exc:
            raise HTTPError(409, "rollout_refused", str(exc)) from None
    except HTTPError as exc:
        services.rollout.metrics.refused.labels(reason=exc.reason).inc()  # counted; nothing else changed
        raise
    return services.rollout.to_json()


def check_admin(services: NetAppServices, token: str | None) -> None:
    """403 on a netapp with no token, cluster key or admin token (anyone could swap its model); 401 unless `token`
    is one of them."""
    settings = services.settings
    if settings.token_sha256 is None and settings.cluster_key is None and settings.admin_token_sha256 is None:
        raise HTTPError(
            403,
            "rollout_forbidden",
            "an open netapp takes no rollout over HTTP: start it with --token-file or --cluster-key-file, or give "
            "netapp serve --candidate",
        )
    by_token = settings.token_sha256 is not None and access.allows(settings.token_sha256, token)
    by_key = (
        settings.cluster_key is not None
        and token is not None
        and hmac.compare_digest(token.encode(), settings.cluster_key)
    )
    by_admin = settings.admin_token_sha256 is not None and access.allows(settings.admin_token_sha256, token)
    if not (by_token or by_key or by_admin):
        raise HTTPError(
            401, "unauthorized", "POST /rollout needs Authorization: Bearer <the netapp's token or cluster key>"
        )


def parse_request(body: bytes) -> tuple[str, str | None, Policy, Shadowing]:
    """`{"candidate": MODEL, "sha256": HEX?, "promote_after": N, ..., "shadow_sample": S, "shadow_budget": B}`;
    HTTPError 422 saying what is wrong."""
    try:
        data = json.loads(body)
    except (ValueError, RecursionError):
        raise HTTPError(422, "invalid_request", 'the body must be JSON: {"candidate": "MODEL", ...}') from None
    if not isinstance(data, dict):
        raise HTTPError(422, "invalid_request", 'the body must be a JSON object: {"candidate": "MODEL", ...}')
    model = data.pop("candidate", None)
    if not isinstance(model, str) or not 0 < len(model) <= MAX_MODEL_CHARS:
        raise HTTPError(
            422, "invalid_request", f"candidate must be a model path or URL of at most {MAX_MODEL_CHARS} characters"
        )
    sha256 = data.pop("sha256", None)
    if sha256 is not None:
        try:
            sha256 = access.check_digest(sha256) if isinstance(sha256, str) else ""
        except ValueError:
            sha256 = ""
        if not sha256:
            raise HTTPError(422, "invalid_request", "sha256 must be 64 hex digits")
    policy_values = _numbers(data, {f.name: f.type for f in fields(Policy)}, "")
    shadow_values = _numbers(data, {f.name: f.type for f in fields(Shadowing)}, "shadow_")
    if data:
        raise HTTPError(422, "invalid_request", f"unknown field(s) {sorted(data)[:5]}: see docs/rollouts.md")
    policy, shadowing = Policy(**policy_values), Shadowing(**shadow_values)
    problem = policy.problem() or shadowing.problem()
    if problem:
        raise HTTPError(422, "invalid_request", problem)
    return model, sha256, policy, shadowing


def _numbers(data: dict[str, Any], names: dict[str, Any], prefix: str) -> dict[str, Any]:
    """The fields of `names` (dataclass field -> its type's name) found in `data` as `prefix + field`, popped, each a
    finite number of the field's kind."""
    out: dict[str, Any] = {}
    for name, kind in names.items():
        key = prefix + name
        if key not in data:
            continue
        value = data.pop(key)
        integer = kind in (int, "int")
        ok = isinstance(value, int) if integer else isinstance(value, int | float)
        if isinstance(value, bool) or not ok or (not integer and value != value) or abs(value) > 1e9:
            raise HTTPError(422, "invalid_request", f"{key} must be {'a whole number' if integer else 'a number'}")
        out[name] = value
    return out
