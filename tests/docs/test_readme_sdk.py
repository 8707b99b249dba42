"""The SDK page's stateful processor runs as written: served, it smooths per robot, and its state moves."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from netapp.client import NetAppClient
from tests.docs.test_readme import DOC_PAGES
from tests.support.raw_robot import RawRobot


def readme_block(marker: str) -> tuple[Path, str]:
    """The one python block of README.md or docs/*.md that contains `marker`, and its page."""
    found = [
        (page, block)
        for page in DOC_PAGES
        for block in re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S)
        if marker in block
    ]
    (page_block,) = found
    return page_block


def test_the_docs_stateful_processor(serve):
    page, code = readme_block("class SmoothedSharpness(StatefulProcessor)")
    assert len(code.strip().splitlines()) < 30
    namespace: dict = {"__name__": "readme"}
    exec(compile(code, str(page), "exec"), namespace)  # noqa: S102 (our own docs)
    server = serve(namespace["SmoothedSharpness"]())
    sharp = np.indices((96, 128)).sum(axis=0) % 2 * 255  # a checkerboard: high sharpness
    frames = [np.zeros((96, 128, 3), np.uint8), np.dstack([sharp] * 3).astype(np.uint8)]
    with NetAppClient(server.url, transport="http") as client:
        for frame in frames:
            client.send(frame)
            assert client.wait_idle(20)
        flat, sharp_result = [r.message for r in client.results(timeout=0.5)]
    assert flat["smoothed"] == 0 and 0 < sharp_result["smoothed"] < sharp_result["sharpness"]
    robot = RawRobot(server.url)
    try:
        robot.init()
        assert list(robot.command({"cmd_type": 4, "data": {"mean": 7.5}})) == [True, "state set"]
        assert list(robot.command({"cmd_type": 3})) == [True, '{"mean":7.5}']
        ok, message = robot.command({"cmd_type": 4, "data": {"mean": "high"}})
        assert not ok and "expected {'mean': number or null}" in message
    finally:
        robot.close()
