"""Robots' priority classes through the middleware (docs/scaling.md#priorities).

A robot's class is in the robots file (`priority`, `auth.robot_priorities`). The netapp learns it from the token the
robot presents: every NetApp the middleware creates takes a class token for each class but the default
(`NETAPP_PRIORITY_TOKENS_SHA256`, digests only), derived from the middleware's key and the NetApp's name like its own
token, and the middleware hands each robot the token of its class instead of the NetApp's. So a robot gets its class
with no change to its code, and cannot claim a higher one: it never sees the token of another class.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import Any

from netapp.protocol import DEFAULT_PRIORITY, PRIORITY_CLASSES, PRIORITY_TOKENS_ENV

CLASSES_WITH_TOKENS = tuple(c for c in PRIORITY_CLASSES if c != DEFAULT_PRIORITY)


def with_env(spec: dict[str, Any], name: str, value: str) -> dict[str, Any]:
    """The spec with the environment variable `name` set to `value` (replacing the spec's own)."""
    env = [e for e in spec.get("env", []) if e.get("name") != name]
    return {**spec, "env": [*env, {"name": name, "value": value}]}


def class_tokens(netapp: str, token_for: Callable[[str], str]) -> dict[str, str]:
    """The NetApp's token of each class but the default (NetApp names have no ':', so none is another's token)."""
    return {c: token_for(f"{netapp}:{c}") for c in CLASSES_WITH_TOKENS}


def with_class_tokens(spec: dict[str, Any], tokens: dict[str, str]) -> dict[str, Any]:
    """The spec with the netapp told which token grants which class: their SHA-256 only, as for its own token."""
    digests = ",".join(f"{c}={hashlib.sha256(t.encode()).hexdigest()}" for c, t in sorted(tokens.items()))
    return with_env(spec, PRIORITY_TOKENS_ENV, digests)
