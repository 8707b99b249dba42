"""The broker message's JSON Schema (docs/broker/result.schema.json), as the tests check every published message."""

from __future__ import annotations

import json
from functools import cache
from typing import Any

import jsonschema

from tests.support.paths import ROOT

SCHEMA_PATH = ROOT / "docs" / "broker" / "result.schema.json"
ASYNCAPI_PATH = ROOT / "docs" / "broker" / "asyncapi.yaml"


@cache
def validator() -> jsonschema.Draft202012Validator:
    schema = json.loads(SCHEMA_PATH.read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def checked(body: bytes) -> dict[str, Any]:
    """`body` parsed, after checking it against the schema (raises jsonschema.ValidationError, saying where)."""
    message = json.loads(body)
    validator().validate(message)
    return message
