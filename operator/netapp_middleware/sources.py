"""Where the robots and the catalogue come from: a YAML file, or one key of a Kubernetes Secret or ConfigMap.

Both kinds are callables returning the parsed document and re-read it when it changes, so rotating a robot's
secret or adding an app needs no restart.
"""

from __future__ import annotations

import base64
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from netapp_operator.kube import Kube

Parse = Callable[[Any], Any]


class FileSource:
    """A YAML file, re-parsed when its modification time or size changes (mounted Secrets and ConfigMaps are
    swapped in place by the kubelet)."""

    def __init__(self, path: str | os.PathLike[str], parse: Parse) -> None:
        self.path = Path(path)
        self._parse = parse
        self._stamp: tuple[float, int] | None = None
        self._value: Any = None

    def __call__(self) -> Any:
        import yaml

        stat = self.path.stat()
        stamp = (stat.st_mtime, stat.st_size)
        if stamp != self._stamp:
            self._value = self._parse(yaml.safe_load(self.path.read_text()))
            self._stamp = stamp
        return self._value


class KubeSource:
    """One key of a Secret or ConfigMap, fetched at most every `ttl_s` seconds.

    Called from the app's worker threads (the sync routes, `run_in_threadpool`), like a file read; the fetch runs
    on the event loop that owns the Kubernetes client."""

    def __init__(
        self, kube: Kube, kind: str, namespace: str, name: str, key: str, parse: Parse, ttl_s: float = 10.0
    ) -> None:
        if kind not in ("Secret", "ConfigMap"):
            raise ValueError(f"kind must be Secret or ConfigMap, not {kind!r}")
        self.kube, self.kind, self.namespace, self.name, self.key = kube, kind, namespace, name, key
        self._parse, self._ttl_s = parse, ttl_s
        self._fetched_at = float("-inf")
        self._value: Any = None

    def __call__(self) -> Any:
        import anyio.from_thread
        import yaml

        if time.monotonic() - self._fetched_at >= self._ttl_s:
            raw = anyio.from_thread.run(self._read)
            self._value = self._parse(yaml.safe_load(raw))
            self._fetched_at = time.monotonic()
        return self._value

    async def _read(self) -> str:
        obj = await self.kube.get(self.kind, self.namespace, self.name)
        if obj is None:
            raise LookupError(f"{self.kind} {self.namespace}/{self.name} not found: create it or fix the name")
        data = obj.get("data") or {}
        if self.key not in data:
            raise KeyError(f"{self.kind} {self.namespace}/{self.name} has no key {self.key!r}")
        return base64.b64decode(data[self.key]).decode() if self.kind == "Secret" else data[self.key]
