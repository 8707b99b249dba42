"""glibc's malloc, set for a netapp at start: the pictures of megabytes a flood brings are returned to the system
when freed, and a frame's own buffers are reused from one frame to the next.

glibc maps a block of its mmap threshold or more on its own and unmaps it when freed. Its default threshold, 128 KiB,
rises to the size of each mapped block freed (up to 32 MiB): after the first 4K picture (25 MB) is freed, pictures and
packets of megabytes come from the heap and the per-thread arenas, which keep their high-water mark, spread over every
thread that ever decoded, converted or received one (docs/benchmarks.md#the-floods-measured-again-issue-22). Setting
the threshold stops that rise, and also stops the trim threshold's (what free memory at the top of a heap is given
back past): left at its 128 KiB, every frame's buffers were given back and faulted in again, and a threshold under a
frame's model input (2 MB for YOLOX-Nano's 416x416 floats) mapped and unmapped that every frame: 1.0 ms more a
640x480 frame (docs/benchmarks.md#the-allocator-measured-issue-24). So both are set: a 640x640 model's input (4.9 MB)
and a 1080p picture stay in the heap, a 4K picture is mapped.
"""

from __future__ import annotations

import ctypes
import logging
import os

log = logging.getLogger(__name__)

MMAP_THRESHOLD_BYTES = 8 * 1024 * 1024
TRIM_THRESHOLD_BYTES = 16 * 1024 * 1024
# mallopt's parameter numbers (malloc.h), and glibc's environment variable for each, which wins when set
PARAMETERS = {
    "M_MMAP_THRESHOLD": (-3, "MALLOC_MMAP_THRESHOLD_", MMAP_THRESHOLD_BYTES),
    "M_TRIM_THRESHOLD": (-1, "MALLOC_TRIM_THRESHOLD_", TRIM_THRESHOLD_BYTES),
}


def set_malloc_thresholds() -> dict[str, int]:
    """Set glibc's mmap and trim thresholds (PARAMETERS), each unless its environment variable is set, in one log
    line; returns what this call set (nothing on another C library)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError, TypeError):  # no C library to look in (Windows), or no mallopt (macOS)
        return {}
    done, said = {}, []
    for name, (number, variable, value) in PARAMETERS.items():
        if os.environ.get(variable):
            said.append(f"{name} {os.environ[variable]} (from {variable})")
        elif mallopt(number, value) == 1:
            done[name] = value
            said.append(f"{name} {value}")
    log.info("malloc: %s", ", ".join(said) or "left as it is")
    return done
