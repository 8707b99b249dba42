"""What each result tells its robot about sending the next frame (`netapp.protocol.HINT_FIELD`): when the netapp will
take it (`next_frame_in_ms`, from `netapp.server.pipeline.next_turn`; docs/client.md#the-next-turn-hint)."""

from __future__ import annotations

from typing import Any


def result_hint(next_frame_in_s: float) -> dict[str, Any]:
    """The `hint` of a result: the next frame is taken `next_frame_in_s` after the result leaves."""
    return {"next_frame_in_ms": round(1000 * next_frame_in_s, 1)}
