"""The link emulator's tests: one echo server per module."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from tests.support.echo import EchoServer


@pytest.fixture(scope="module")
def echo_server() -> Iterator[EchoServer]:
    srv = EchoServer()
    t = threading.Thread(target=srv.serve_forever, daemon=True)
    t.start()
    yield srv
    srv.shutdown()
    srv.server_close()
