"""The unmodified era-5g-client as a robot in tests: registered with a netapp, its results on a queue."""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest


@contextmanager
def era_robot(url: str, **args: Any) -> Iterator[tuple[Any, queue.Queue]]:
    """(the registered `NetAppClientBase`, the queue its JSON results arrive on); skips where it is not installed."""
    era = pytest.importorskip("era_5g_client.client_base", reason="era-5g-client is not installed (make install)")
    from era_5g_interface.channels import CallbackInfoClient, ChannelType

    got: queue.Queue = queue.Queue()
    client = era.NetAppClientBase({"results": CallbackInfoClient(ChannelType.JSON, got.put)})
    client.register(url, args=args)
    try:
        assert client.initialized
        yield client, got
    finally:
        # python-engineio's threaded client can lose a race between disconnect() and its write loop and then wait
        # out a ping interval (upstream): disconnect in the background; the server side is checked elsewhere.
        threading.Thread(target=client.disconnect, daemon=True).start()
