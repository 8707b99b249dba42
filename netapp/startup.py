"""A command's start-up without the cyclic garbage collector.

Starting `netapp serve` imports some thousand modules and builds their classes and tables: objects that live as
long as the process. The collector, run every few hundred allocations, walks them again and again and finds nothing
to free; paused, the imports take a fifth less (measured: docs/benchmarks.md#cold-start). Once started, the objects
made so far are frozen (`gc.freeze`: out of every later collection, so that no full collection walks them on a
robot's first frames) and the collector runs as usual again.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator


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
