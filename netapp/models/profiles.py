"""Which accuracy profile (netapp/client/profiles/NAME.json, made by `python -m bench.accuracy`) was made for a
model: the one that records the model file's sha256. None when no profile was made for this model."""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path

PROFILES_DIR = Path(__file__).resolve().parents[1] / "client" / "profiles"
SHA256_FIELD = "model_sha256"


def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


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
    return profiles_by_model(directory).get(file_sha256(model_path))
