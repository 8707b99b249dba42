"""A command's start-up: without the cyclic garbage collector, and without the libraries it does not use yet.

Starting `netapp serve` imports some thousand modules and builds their classes and tables: objects that live as
long as the process. The collector, run every few hundred allocations, walks them again and again and finds nothing
to free; paused, the imports take a fifth less (measured: docs/benchmarks.md#cold-start). Once started, the objects
made so far are frozen (`gc.freeze`: out of every later collection, so that no full collection walks them on a
robot's first frames) and the collector runs as usual again.

Some libraries import others for features a netapp may never use: python-socketio imports aiohttp, requests and
websocket-client (its clients) and aio_pika (a manager) whatever the server needs, about 150 ms. `deferred` gives
the modules that import such a library a placeholder, which imports it the first time something is read from it.
"""

from __future__ import annotations

import contextlib
import gc
import importlib
import importlib.machinery
import sys
import types
from collections.abc import Iterator, Sequence
from importlib.machinery import ModuleSpec
from types import ModuleType
from typing import Any

# What python-socketio imports for its clients and its AMQP manager: a netapp's Socket.IO server uses none of them
SOCKETIO_CLIENTS = ("aiohttp", "aio_pika", "requests", "websocket")


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """Run the block without the cyclic collector; after it, freeze what it made and collect as before (a nested
    or an already paused block leaves the collector as it found it)."""
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.freeze()
            gc.enable()


class _Placeholder(types.ModuleType):
    """What a module imported within `deferred` got for a named library: the library itself is imported, as usual,
    the first time something is read from this (thread-safe: the import system's own lock)."""

    def __init__(self, name: str, wanted: set[str]) -> None:
        super().__init__(name)
        self._wanted = wanted

    def __getattr__(self, attr: str) -> Any:  # only what the placeholder itself lacks
        if attr.startswith("__"):  # the import system's probes (__path__, __file__, ...)
            raise AttributeError(attr)
        name = self.__name__
        self._wanted.add(name)  # a finder still active lets it through now
        if sys.modules.get(name) is self:
            del sys.modules[name]
        return getattr(importlib.import_module(name), attr)


class _Deferring:
    """A meta path finder and loader: `names` (installed ones) as placeholders, while active (no importlib.abc base
    classes: importing them costs a netapp 15 ms)."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = frozenset(names)
        self.wanted: set[str] = set()

    def find_spec(self, name: str, path: Sequence[str] | None, target: ModuleType | None = None) -> ModuleSpec | None:
        if name not in self.names or name in self.wanted or importlib.machinery.PathFinder.find_spec(name) is None:
            return None  # not named, wanted for real, or not installed (ImportError as without this finder)
        return ModuleSpec(name, self)

    def create_module(self, spec: ModuleSpec) -> ModuleType:
        return _Placeholder(spec.name, self.wanted)

    def exec_module(self, module: ModuleType) -> None:
        pass


@contextlib.contextmanager
def deferred(*names: str) -> Iterator[None]:
    """Within the block, importing one of `names` (top-level modules not imported yet) gives a placeholder that
    imports it the first time something is read from it; after the block, importing them imports them as usual."""
    finder = _Deferring(names)
    sys.meta_path.insert(0, finder)
    try:
        yield
    finally:
        sys.meta_path.remove(finder)
        for name in names:
            if isinstance(sys.modules.get(name), _Placeholder):
                del sys.modules[name]
