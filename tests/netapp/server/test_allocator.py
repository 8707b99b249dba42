"""glibc's mmap threshold, fixed by `netapp serve` (netapp.server.runner.fix_mmap_threshold): a block of a megabyte
or more freed after a 25 MB picture still goes back to the system, not into an arena that keeps it."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")

# In a fresh interpreter: free a 25 MB mapped block (what a 4K BGR picture is), then allocate 2 MiB and print whether
# glibc mapped it on its own (the IS_MMAPPED bit of the chunk's size word, just before the block).
PROBE = """
import ctypes, sys
from netapp.server.runner import fix_mmap_threshold
if sys.argv[1] == "fixed":
    assert fix_mmap_threshold()
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
libc.free(libc.malloc(25 * 2**20))
block = libc.malloc(2 * 2**20)
print(bool(ctypes.c_size_t.from_address(block - ctypes.sizeof(ctypes.c_size_t)).value & 2))
"""


def mapped_after_a_picture(mode: str) -> bool:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, env=env, check=True)
    return out.stdout.strip() == "True"


def test_a_megabyte_block_is_mapped_after_a_picture_was_freed():
    assert mapped_after_a_picture("fixed")
    # glibc's default: the threshold rose to 25 MB with the free, the block came from the heap (kept when freed)
    assert not mapped_after_a_picture("default")
