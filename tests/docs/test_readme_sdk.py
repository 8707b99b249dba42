"""The README's stateful processor runs as written: served, it smooths per robot, and its state moves."""

from __future__ import annotations

import re

import numpy as np

from netapp.client import NetAppClient
from tests.support.paths import ROOT
from tests.support.raw_robot import RawRobot

README = ROOT / "README.md"


def readme_block(marker: str) -> str:
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    (block,) = [b for b in blocks if marker in b]
    return block


def test_the_readme_stateful_processor(serve):
    code = readme_block("class SmoothedSharpness(StatefulProcessor)")
    assert len(code.strip().splitlines()) < 30
    namespace: dict = {"__name__": "readme"}
    exec(compile(code, str(README), "exec"), namespace)  # noqa: S102 (our own README)
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
