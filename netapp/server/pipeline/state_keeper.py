"""The state of a stateful processor, per robot session: created with the session, updated after each of its
frames on the inference thread, and moved as bounded JSON by the 5G-ERA state commands and by checkpoints.

Whatever reads or changes a state runs on the inference thread (the pipeline's `exclusive`), so a command never
sees a state half-way through a frame; parsing a state from the network and file I/O run beside it.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import tempfile
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from netapp.protocol import STATE_CHECKPOINT_ARG, STATE_KEY
from netapp.sdk.processor import Processor, StatefulProcessor
from netapp.sdk.session_state import StateError, dump_state, load_state

MAX_CHECKPOINT_EVERY = 10_000
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


@dataclass
class SessionState:
    value: Any
    checkpoint_every: int = 0  # frames between checkpoints in results; 0: none
    since_checkpoint: int = 0


class StateKeeper:
    """What the transports call for session state; a no-op for a stateless processor."""

    def __init__(
        self,
        processor: Processor,
        exclusive: Callable[..., Awaitable[Any]],
        state_dir: str | None = None,
        max_saved: int = 10_000,
    ) -> None:
        """`exclusive(fn, *args)` runs fn on the inference thread, between batches (`Pipeline.exclusive`)."""
        self.processor = processor if isinstance(processor, StatefulProcessor) else None
        self._exclusive = exclusive
        self.state_dir = Path(state_dir) if state_dir else None
        self.max_saved = max_saved

    @property
    def max_state_bytes(self) -> int:
        return self._require().max_state_bytes

    def open(self, args: dict[str, Any]) -> SessionState | None:
        """A new session's state; ValueError for a bad checkpoint request in its INIT arguments."""
        if self.processor is None:
            return None
        every = args.get(STATE_CHECKPOINT_ARG, 0)
        if not isinstance(every, int) or isinstance(every, bool) or not 0 <= every <= MAX_CHECKPOINT_EVERY:
            raise ValueError(f"'{STATE_CHECKPOINT_ARG}' must be an integer from 0 (none) to {MAX_CHECKPOINT_EVERY}")
        return SessionState(self.processor.new_state(args), checkpoint_every=every)

    def after_process(self, state: SessionState | None, result: dict[str, Any], timestamp: int) -> dict[str, Any]:
        """The frame's final result: the processor's `update`, and every `checkpoint_every` frames the state."""
        if self.processor is None or state is None:
            return result
        result = self.processor.update(state.value, result, timestamp)
        if state.checkpoint_every:
            state.since_checkpoint += 1
            if state.since_checkpoint >= state.checkpoint_every:
                state.since_checkpoint = 0
                try:
                    result[STATE_KEY] = json.loads(dump_state(self.processor, state.value))
                except StateError as exc:  # the result still goes out, saying why it carries no checkpoint
                    result[STATE_KEY + "_error"] = str(exc)
        return result

    # -- the state commands: reading and replacing the state on the inference thread, the rest beside it -----------

    async def reset(self, state: SessionState, args: dict[str, Any]) -> None:
        processor = self._require()
        await self._exclusive(self._replace, state, processor.new_state(args))

    async def get(self, state: SessionState) -> str:
        return await self._exclusive(dump_state, self._require(), state.value)

    async def set(self, state: SessionState, data: Any) -> None:
        """Parse and check `data` off the inference thread (a large hostile state stalls no other robot), then
        swap it in between frames. StateError leaves the session's state as it was."""
        value = await asyncio.to_thread(load_state, self._require(), data)
        await self._exclusive(self._replace, state, value)

    async def save(self, state: SessionState, name: Any) -> None:
        path = self._path(name)
        text = await self.get(state)
        await asyncio.to_thread(self._write, path, text)

    async def load(self, state: SessionState, name: Any) -> None:
        path = self._path(name)
        await self.set(state, await asyncio.to_thread(self._read, path, name))

    @staticmethod
    def _replace(state: SessionState, value: Any) -> None:
        state.value = value
        state.since_checkpoint = 0

    def _write(self, path: Path, text: str) -> None:
        if not path.exists() and sum(1 for _ in path.parent.glob("*.json")) >= self.max_saved:
            raise StateError(f"{path.parent} already holds {self.max_saved} saved states; delete some first")
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False, suffix=".part") as tmp:
            tmp.write(text)
        os.replace(tmp.name, path)  # a crash mid-write never leaves half a state under the name

    def _read(self, path: Path, name: str) -> str:
        limit = self._require().max_state_bytes
        try:
            size = path.stat().st_size
        except FileNotFoundError:
            raise StateError(f"no saved state named {name!r}; SAVE_STATE it first") from None
        if size > limit:
            raise StateError(f"the saved state {name!r} is {size} bytes, over the {limit}-byte limit")
        return path.read_text(encoding="utf-8")

    def _path(self, name: Any) -> Path:
        if self.state_dir is None:
            raise StateError("this netapp keeps no saved states: start it with --state-dir DIR")
        if not isinstance(name, str) or not _NAME.fullmatch(name):
            raise StateError(
                "a saved state's name is 1 to 64 letters, digits, '.', '_' or '-', not starting with a dot"
            )
        return self.state_dir / f"{name}.json"

    def _require(self) -> StatefulProcessor:
        if self.processor is None:
            raise StateError("this netapp's processor keeps no state")
        return self.processor
