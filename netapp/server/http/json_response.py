"""A JSON response encoded by `netapp.wire_json` (a frame's result, on the data path), not by the standard library."""

from __future__ import annotations

from typing import Any

from fastapi.responses import JSONResponse

from netapp import wire_json


class WireJSONResponse(JSONResponse):
    def render(self, content: Any) -> bytes:
        return wire_json.dumpb(content)
