"""Session state as JSON text, bounded: what the state commands and checkpoints of a stateful processor carry."""

from __future__ import annotations

import json
from typing import Any

from netapp.sdk.processor import StatefulProcessor


class StateError(ValueError):
    """A state that cannot be saved or restored; the message says why."""


def dump_state(processor: StatefulProcessor, state: Any) -> str:
    """The state as compact JSON text, at most `processor.max_state_bytes` long."""
    try:
        text = json.dumps(processor.state_to_json(state), separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError, RecursionError) as exc:
        raise StateError(f"{processor.name}: the state is not JSON data: {exc}") from exc
    if len(text) > processor.max_state_bytes:
        raise StateError(
            f"{processor.name}: the state is {len(text)} bytes, over the {processor.max_state_bytes}-byte limit"
        )
    return text


def load_state(processor: StatefulProcessor, data: Any) -> Any:
    """A state from JSON text or already-parsed JSON data (e.g. a SET_STATE command's `data`). StateError for a
    state too large or invalid; the size is checked before anything is parsed or built."""
    limit = processor.max_state_bytes
    if isinstance(data, (bytes, bytearray)):
        data = bytes(data).decode("utf-8", errors="replace")
    if isinstance(data, str):
        if len(data) > limit:
            raise StateError(f"a state of {len(data)} bytes is over the {limit}-byte limit of {processor.name}")
        try:
            data = json.loads(data)
        except ValueError as exc:
            raise StateError(f"the state is not valid JSON: {exc}") from exc
    else:
        try:
            size = len(json.dumps(data, separators=(",", ":"), allow_nan=False))
        except (TypeError, ValueError, RecursionError) as exc:
            raise StateError(f"the state is not JSON data: {exc}") from exc
        if size > limit:
            raise StateError(f"a state of {size} bytes is over the {limit}-byte limit of {processor.name}")
    try:
        return processor.state_from_json(data)
    except (ValueError, TypeError, KeyError) as exc:
        raise StateError(f"{processor.name} cannot restore this state: {exc}") from exc
