"""How a netapp pod gets its model (pure): mounted from the NetApp's volume, or fetched by an init container.

A model with a sha256 is downloaded once per node, not once per pod: the init container keeps each model it fetched
in the node's cache (a hostPath, `OperatorConfig.model_cache_dir`), named by its sha256, and the next pod on that
node, of any NetApp, copies it from there. The cache is never trusted by name: the pod's own copy is checked against
the sha256 the NetApp asks for, and only a copy that matches is served; a missing, partial or forged cache entry means
a download, which is checked the same way before the pod (and the cache) keeps it. Writing the cache is best effort
(a node whose cache directory the netapp's uid cannot write still downloads and serves, once per pod). A model
without a sha256 cannot be verified, so it is neither taken from nor put in the cache: downloaded per pod as before.
"""

from __future__ import annotations

from typing import Any

from netapp_operator import spec as specs
from netapp_operator.config import OperatorConfig
from netapp_operator.spec import NetAppSpec

CACHE_MOUNT = "/cache"  # where the init container sees the node's model cache

# Download to a temporary name, check, then rename: the server never sees a partial or forged file, and a stalled
# download ends at --max-time instead of hanging the pod forever.
DOWNLOAD = (
    "curl --fail --silent --show-error --location --retry 3 "
    '--connect-timeout 15 --max-time "$MODEL_TIMEOUT" --output "$MODEL_PATH.part" "$MODEL_URL"'
)
CHECK = 'echo "$MODEL_SHA256  $MODEL_PATH.part" | sha256sum -c -'
FETCH = f'set -eu; {DOWNLOAD}; if [ -n "$MODEL_SHA256" ]; then {CHECK}; fi; mv "$MODEL_PATH.part" "$MODEL_PATH"'
# The pod's copy of the cache entry is what is checked (a file swapped after a check of the entry itself would be
# served unchecked); the download is kept in the cache under a name of the pod's own first (HOSTNAME: two pods on a
# node may fetch at once), renamed when whole.
FETCH_CACHED = (
    'set -eu; cached="$MODEL_CACHE/$MODEL_SHA256"; '
    f'if [ -f "$cached" ] && cp "$cached" "$MODEL_PATH.part" && {CHECK} >/dev/null 2>&1; then '
    'echo "model $MODEL_SHA256: from the node\'s cache"; '
    f"else {DOWNLOAD}; {CHECK}; "
    'tmp="$MODEL_CACHE/.$MODEL_SHA256.$HOSTNAME"; '
    'if cp "$MODEL_PATH.part" "$tmp" 2>/dev/null && mv -f "$tmp" "$cached"; then '
    'echo "model $MODEL_SHA256: downloaded, kept in the node\'s cache"; '
    'else rm -f "$tmp"; echo "model $MODEL_SHA256: downloaded; the node\'s cache is not writable"; fi; fi; '
    'mv "$MODEL_PATH.part" "$MODEL_PATH"'
)


def model_files(
    spec: NetAppSpec, config: OperatorConfig, security: dict[str, Any]
) -> tuple[str | None, list[dict], list[dict], list[dict]]:
    """(the model's file in the pod, init containers, volumes, mounts): the spec's model, or the operator's default,
    fetched by an init container (through the node's cache when it has a sha256) or mounted from its volume.
    `security`: the init container's securityContext."""
    if spec.custom_processor:  # it loads its own weights: no model, no default one either
        return None, [], [], []
    model = spec.model
    if model is None and config.default_model_url:
        model = specs.Model(url=config.default_model_url, sha256=config.default_model_sha256 or None)
    if model is None:
        return None, [], [], []
    if model.has_volume:
        path = f"{specs.MODEL_DIR}/{str(model.volume_path).lstrip('/')}"
        return (
            path,
            [],
            [{"name": "model", "persistentVolumeClaim": {"claimName": model.volume_claim, "readOnly": True}}],
            [{"name": "model", "mountPath": specs.MODEL_DIR, "readOnly": True}],
        )
    target = f"{specs.MODEL_DIR}/{specs.MODEL_FILE}"
    sha256 = (model.sha256 or "").lower()
    cached = bool(sha256 and config.model_cache_dir)
    init = {
        "name": "fetch-model",
        "image": config.model_init_image,
        "command": ["sh", "-c", FETCH_CACHED if cached else FETCH],
        "env": [
            {"name": "MODEL_URL", "value": model.url},
            {"name": "MODEL_SHA256", "value": sha256},
            {"name": "MODEL_TIMEOUT", "value": str(int(model.timeout_seconds))},
            {"name": "MODEL_PATH", "value": target},
            *([{"name": "MODEL_CACHE", "value": CACHE_MOUNT}] if cached else []),
        ],
        "resources": {"requests": {"cpu": "50m", "memory": "64Mi"}, "limits": {"memory": "128Mi"}},
        "securityContext": security,
        "volumeMounts": [
            {"name": "model", "mountPath": specs.MODEL_DIR},
            *([{"name": "model-cache", "mountPath": CACHE_MOUNT}] if cached else []),
        ],
    }
    volumes: list[dict[str, Any]] = [{"name": "model", "emptyDir": {}}]
    if cached:
        cache = {"path": config.model_cache_dir, "type": "DirectoryOrCreate"}
        volumes.append({"name": "model-cache", "hostPath": cache})
    return target, [init], volumes, [{"name": "model", "mountPath": specs.MODEL_DIR, "readOnly": True}]
