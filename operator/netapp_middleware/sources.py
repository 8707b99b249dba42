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
from typing import Any

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
    """One key of a Secret or ConfigMap, fetched at most every `ttl_s` seconds."""

    def __init__(
        self, core_api: Any, kind: str, namespace: str, name: str, key: str, parse: Parse, ttl_s: float = 10.0
    ) -> None:
        if kind not in ("Secret", "ConfigMap"):
            raise ValueError(f"kind must be Secret or ConfigMap, not {kind!r}")
        self._api, self.kind, self.namespace, self.name, self.key = core_api, kind, namespace, name, key
        self._parse, self._ttl_s = parse, ttl_s
        self._fetched_at = float("-inf")
        self._value: Any = None

    def __call__(self) -> Any:
        import yaml

        if time.monotonic() - self._fetched_at >= self._ttl_s:
            if self.kind == "Secret":
                obj = self._api.read_namespaced_secret(self.name, self.namespace)
                raw = base64.b64decode((obj.data or {})[self.key]).decode()
            else:
                obj = self._api.read_namespaced_config_map(self.name, self.namespace)
                raw = (obj.data or {})[self.key]
            self._value = self._parse(yaml.safe_load(raw))
            self._fetched_at = time.monotonic()
        return self._value
