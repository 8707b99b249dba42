"""Where a model comes from: a local path, or a URL downloaded once into a cache, with a timeout and a checksum."""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlparse

if TYPE_CHECKING:
    import requests

DEFAULT_CACHE = Path(os.environ.get("NETAPP_CACHE", Path.home() / ".cache" / "netapp")) / "models"


class ModelUnavailable(Exception):
    """The model cannot be had; the message says why and what to do."""


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def split_checksum(spec: str) -> tuple[str, str | None]:
    """`URL#sha256=HEX` -> (URL, HEX)."""
    if "#sha256=" in spec:
        url, digest = spec.split("#sha256=", 1)
        return url, digest.strip().lower()
    return spec, None


def resolve_model(
    spec: str,
    sha256: str | None = None,
    cache_dir: Path = DEFAULT_CACHE,
    timeout_s: float = 60,
    option: str = "--model",
    what: str = "the model",
) -> Path:
    """A local file path for `spec` (a path or an http(s) URL, optionally `#sha256=...`); `option` names the
    command-line option and `what` the file in error messages."""
    spec, embedded = split_checksum(spec)
    expected = (sha256 or embedded or "").lower() or None
    if urlparse(spec).scheme in ("http", "https"):
        return _download(spec, expected, cache_dir, timeout_s, option, what)
    path = Path(spec).expanduser()
    if not path.is_file():
        raise ModelUnavailable(f"file {path} does not exist (pass {option} PATH or an http(s) URL)")
    if expected and sha256_of(path) != expected:
        raise ModelUnavailable(f"file {path} does not match sha256 {expected}")
    return path


def download_failure(exc: requests.RequestException, timeout_s: float) -> str:
    """A few words for why a download failed (not urllib3's whole chain)."""
    import requests

    if isinstance(exc, requests.HTTPError) and exc.response is not None:
        return f"HTTP {exc.response.status_code} {exc.response.reason or ''}".strip()
    if isinstance(exc, requests.Timeout):
        return f"no answer within {timeout_s:g} s"
    if isinstance(exc, requests.ConnectionError):
        return "cannot connect (no network, or a wrong address)"
    return type(exc).__name__


def _download(url: str, expected: str | None, cache_dir: Path, timeout_s: float, option: str, what: str) -> Path:
    name = Path(urlparse(url).path).name or "model.onnx"
    key = expected[:16] if expected else hashlib.sha256(url.encode()).hexdigest()[:16]
    target = cache_dir / f"{key}-{name}"
    if target.is_file() and (not expected or sha256_of(target) == expected):
        return target
    cache_dir.mkdir(parents=True, exist_ok=True)
    make_var = option.lstrip("-").upper()
    import requests  # here: a model on disk loads without it (~90 ms of a netapp's start)

    hint = f"without network access, download it elsewhere and pass the file: {option} PATH (make demo {make_var}=PATH)"
    try:
        with requests.get(url, stream=True, timeout=timeout_s) as response:
            response.raise_for_status()
            with tempfile.NamedTemporaryFile(dir=cache_dir, delete=False, suffix=".part") as tmp:
                for chunk in response.iter_content(1 << 20):
                    tmp.write(chunk)
    except requests.RequestException as exc:
        why = download_failure(exc, timeout_s)
        raise ModelUnavailable(f"cannot download {what} from {url}: {why}; {hint}") from exc
    tmp_path = Path(tmp.name)
    if expected and sha256_of(tmp_path) != expected:
        tmp_path.unlink(missing_ok=True)
        raise ModelUnavailable(f"the file downloaded from {url} does not match sha256 {expected}")
    tmp_path.replace(target)
    return target
