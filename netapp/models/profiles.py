"""Which accuracy profile (netapp/profiles/NAME.json, made by `netapp profile MODEL`) was made for a
model: the one that records the model file's sha256. None when no profile was made for this model."""

from __future__ import annotations

import functools
import json
from pathlib import Path

from netapp.accuracy import PROFILES as PROFILES_DIR
from netapp.models.source import sha256_of

SHA256_FIELD = "model_sha256"


@functools.cache
def profiles_by_model(directory: Path = PROFILES_DIR) -> dict[str, str]:
    """{model sha256: profile name} of the profiles that record their model."""
    found = {}
    for path in sorted(directory.glob("*.json")):
        try:
            digest = json.loads(path.read_text(encoding="utf-8")).get(SHA256_FIELD)
        except (OSError, ValueError, AttributeError):
            continue
        if isinstance(digest, str):
            found[digest.lower()] = path.stem
    return found


def profile_for(model_path: str | Path, directory: Path = PROFILES_DIR) -> str | None:
    """The name of the profile made for this model file, or None."""
    return profiles_by_model(directory).get(sha256_of(Path(model_path)))
