"""The cameras' results written by the netapp itself (`netapp serve --source-results DIR`): one JSON line per result
in DIR/NAME.jsonl, each the message `netapp watch` prints (docs/cameras.md#results).

Bounded: a file that reaches `max_bytes` is renamed NAME.jsonl.1 (the older .1 goes to .2, and so on), and at most
KEEP old files are kept, so a camera's results never take more than (KEEP + 1) x max_bytes. A line is written
whole or not at all (each line is one write); a full disk or a removed folder is said once and the result dropped,
never the netapp stopped.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import IO, Any

log = logging.getLogger(__name__)

KEEP = 3  # old files per camera, beside the one being written
DEFAULT_MAX_BYTES = 64 * 1024 * 1024


def rotated(path: Path, index: int) -> Path:
    return path.with_name(f"{path.name}.{index}")


class ResultsFiles:
    """One rotating JSON-lines file per camera in `folder`. Closed with the netapp."""

    def __init__(self, folder: str | os.PathLike, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        self.folder = Path(folder)
        self.max_bytes = max_bytes
        self._open: dict[str, tuple[IO[bytes], int]] = {}  # camera -> (file, its size)
        self._failing: set[str] = set()

    def path(self, camera: str) -> Path:
        return self.folder / f"{camera}.jsonl"  # camera names are checked as DNS labels (naming.py): no "/" nor ".."

    def write(self, camera: str, message: dict[str, Any]) -> None:
        line = (json.dumps(message, separators=(",", ":")) + "\n").encode()
        try:
            handle, size = self._open.get(camera) or self._start(camera)
            if size and size + len(line) > self.max_bytes:
                handle.close()
                self._rotate(camera)
                handle, size = self._start(camera)
            handle.write(line)
            handle.flush()  # a reader (tail -f, a collector) sees whole lines as they come
            self._open[camera] = (handle, size + len(line))
            self._failing.discard(camera)
        except OSError as exc:
            self._open.pop(camera, None)
            if camera not in self._failing:
                log.error("camera %s: cannot write its results to %s (%s); dropping them", camera, self.folder, exc)
                self._failing.add(camera)

    def _start(self, camera: str) -> tuple[IO[bytes], int]:
        self.folder.mkdir(parents=True, exist_ok=True)
        handle = open(self.path(camera), "ab")  # noqa: SIM115 (kept open between results, closed by close())
        return handle, handle.tell()

    def _rotate(self, camera: str) -> None:
        path = self.path(camera)
        rotated(path, KEEP).unlink(missing_ok=True)
        for index in range(KEEP - 1, 0, -1):
            if rotated(path, index).exists():
                rotated(path, index).rename(rotated(path, index + 1))
        path.rename(rotated(path, 1))

    def close(self) -> None:
        for handle, _ in self._open.values():
            handle.close()
        self._open.clear()
