"""Download a model at image build time (only with --build-arg MODEL_URL): bounded in time, checked by sha256."""

import hashlib
import os
import sys
import urllib.request

url, sha256, target = sys.argv[1], sys.argv[2], sys.argv[3]
if not sha256:
    sys.exit("MODEL_SHA256 is required with MODEL_URL: a baked-in model must be verifiable")
digest = hashlib.sha256()
with urllib.request.urlopen(url, timeout=60) as response, open(target + ".part", "wb") as out:  # noqa: S310
    for chunk in iter(lambda: response.read(1 << 20), b""):
        digest.update(chunk)
        out.write(chunk)
if digest.hexdigest() != sha256.lower():
    sys.exit(f"checksum mismatch for {url}: got {digest.hexdigest()}, want {sha256}")
os.replace(target + ".part", target)
print(f"model {url} -> {target} ({digest.hexdigest()})")
