"""netapp.serve_process.wait_http_ok, the one readiness poller: for a Popen, for an asyncio process waited on through a
thread (the middleware's local backend), and stopped by its cancel event."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import threading

import pytest

from netapp.serve_process import free_port, wait_http_ok


def nobody_listens() -> str:
    return f"http://127.0.0.1:{free_port()}/readyz"


def test_a_popen_that_exits_ends_the_wait() -> None:
    process = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    process.wait()
    with pytest.raises(RuntimeError, match="exited with code 3"):
        wait_http_ok(nobody_listens(), process, timeout_s=30)


async def test_an_asyncio_process_that_exits_ends_the_wait_in_a_thread() -> None:
    process = await asyncio.create_subprocess_exec(sys.executable, "-c", "raise SystemExit(4)")
    await process.wait()
    with pytest.raises(RuntimeError, match="exited with code 4"):
        await asyncio.to_thread(wait_http_ok, nobody_listens(), process, 30)


def test_the_cancel_event_ends_the_wait() -> None:
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(RuntimeError, match="stopped waiting"):
        wait_http_ok(nobody_listens(), timeout_s=30, cancel=cancel)


def test_the_deadline_ends_the_wait() -> None:
    with pytest.raises(RuntimeError, match="did not answer within"):
        wait_http_ok(nobody_listens(), timeout_s=0.2)
