"""glibc's thresholds, set by `netapp serve` (netapp.server.allocator.set_malloc_thresholds): a block over the mmap
threshold freed after a 25 MB picture still goes back to the system, not into an arena that keeps it; a frame's
buffers (a model input of 2 MB) come from the heap, and freeing them does not give the heap back to be faulted in again
on the next frame."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from netapp.server.allocator import MMAP_THRESHOLD_BYTES

pytestmark = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")

# In a fresh interpreter: free a 25 MB mapped block (what a 4K BGR picture is), then allocate SIZE bytes and print
# whether glibc mapped it on its own (the IS_MMAPPED bit of the chunk's size word, just before the block); then free
# it and print the heap's size (mallinfo2's `arena`): a heap given back shrinks.
PROBE = """
import ctypes, sys
from netapp.server.allocator import MMAP_THRESHOLD_BYTES, PARAMETERS, set_malloc_thresholds
mode, size = sys.argv[1], int(sys.argv[2])
if mode == "set":
    assert set_malloc_thresholds() == {name: value for name, (_, _, value) in PARAMETERS.items()}
elif mode == "mmap-only":  # what netapp serve did before issue 24: the trim threshold stays at 128 KiB
    ctypes.CDLL(None).mallopt(PARAMETERS["M_MMAP_THRESHOLD"][0], MMAP_THRESHOLD_BYTES)
class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost".split()]
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
libc.mallinfo2.restype = MallInfo2
libc.free(libc.malloc(25 * 2**20))
block = libc.malloc(size)
mapped = bool(ctypes.c_size_t.from_address(block - ctypes.sizeof(ctypes.c_size_t)).value & 2)
libc.free(block)
print(mapped, libc.mallinfo2().arena)
"""


def after_a_picture(mode: str, size: int) -> tuple[bool, int]:
    """(whether a block of `size` bytes was mapped on its own, the heap's size once it was freed)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    out = subprocess.run(
        [sys.executable, "-c", PROBE, mode, str(size)], capture_output=True, text=True, env=env, check=True
    )
    mapped, heap = out.stdout.split()
    return mapped == "True", int(heap)


def test_a_block_over_the_threshold_is_mapped_after_a_picture_was_freed():
    assert after_a_picture("set", 2 * MMAP_THRESHOLD_BYTES)[0]
    # glibc's default: the threshold rose to 25 MB with the free, the block came from the heap (kept when freed)
    assert not after_a_picture("default", 2 * MMAP_THRESHOLD_BYTES)[0]


def test_a_frames_model_input_comes_from_the_heap_and_stays_there():
    size = 3 * 2**20  # a 416x416x3 float input is 2 MB; a heap that kept 3 MiB kept it
    mapped, heap = after_a_picture("set", size)
    assert not mapped
    assert heap >= size
    # The mmap threshold alone left the trim threshold at 128 KiB: the heap was given back, every frame.
    mapped, heap = after_a_picture("mmap-only", size)
    assert not mapped
    assert heap < size


def test_the_environment_wins():
    env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": "65536", "MALLOC_TRIM_THRESHOLD_": "131072"}
    code = "from netapp.server.allocator import set_malloc_thresholds as s; print(s())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip() == "{}"
