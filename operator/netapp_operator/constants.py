"""Names and defaults shared by the operator, the middleware, the chart tests and the benchmarks: each one here only.

Pure data, no imports beyond the wire protocol's port, so the middleware and the robot-side tools can import it
without kopf or a Kubernetes client.
"""

from __future__ import annotations

from netapp.protocol import DEFAULT_PORT

# The custom resources.
GROUP = "netapp.dev"
VERSION = "v1alpha1"
API_VERSION = f"{GROUP}/{VERSION}"
NETAPP_KIND, NETAPP_PLURAL = "NetApp", "netapps"
NODEPOOL_KIND, NODEPOOL_PLURAL = "NodePool", "nodepools"

# Where a pod finds its own namespace (the middleware's default namespace in a cluster).
SERVICE_ACCOUNT_NAMESPACE_FILE = "/var/run/secrets/kubernetes.io/serviceaccount/namespace"

# Who manages an object (the field manager of server-side apply, and the managed-by label's value).
OPERATOR_MANAGER = "netapp-operator"
MIDDLEWARE_MANAGER = "netapp-middleware"

# Labels and annotations.
LABEL_NAME = "app.kubernetes.io/name"
LABEL_INSTANCE = "app.kubernetes.io/instance"
LABEL_MANAGED_BY = "app.kubernetes.io/managed-by"
LABEL_POOL = f"{GROUP}/pool"  # on a child: the pool it runs on; on a node: the pool it belongs to (by convention)
LABEL_APP = f"{GROUP}/app"  # a middleware NetApp: the catalogue app it runs
LABEL_ROLE = f"{GROUP}/role"  # on a child: "standby" for a NetApp's warm standby (spec.standby)
LABEL_SHARED = f"{GROUP}/shared"  # a middleware NetApp: whether several robots may share it
ANNOTATION_APP = f"{GROUP}/app"
ANNOTATION_PLACEMENT = f"{GROUP}/placement"
# The W3C traceparent of the deployment that created the NetApp (docs/tracing.md): its reconcile joins that trace.
ANNOTATION_TRACEPARENT = f"{GROUP}/traceparent"
ANNOTATION_MODEL = f"{GROUP}/model"  # on a NetApp's Deployment: the model it serves (netapp_operator.rollouts)
ANNOTATION_CLAIMS = f"{GROUP}/claims"  # a middleware NetApp: which robots use it, so a restarted middleware knows
ANNOTATION_WAKE = f"{GROUP}/wake"  # on a NetApp: a new value wakes it from its sleep (netapp_operator.idle)
NETAPP_APP_NAME = "netapp"  # the name label of every netapp's children

# Replicas going away (scale-down, rolling update, node drain): the pod sleeps in preStop while its endpoint is
# removed from the Service, then on SIGTERM the netapp drains (readiness 503, robots told to move) for at most
# DRAIN_GRACE_S, then uvicorn closes what is left (up to 5 s). The grace period covers all three, with a margin.
PRESTOP_SLEEP_S = 5
DRAIN_GRACE_S = 20
TERMINATION_GRACE_S = PRESTOP_SLEEP_S + DRAIN_GRACE_S + 10
READINESS_PERIOD_S = 2  # a draining replica's 503 takes it out of the Service within one period
# The key a NetApp's replicas share (netapp.server.cluster.ownership): a Secret per NetApp, made once by the operator.
CLUSTER_KEY_SECRET_KEY = "key"
# A NetApp's access token: a Secret the operator creates once (never rotated), read by the netapp (env) and the
# middleware (which hands it to robots with the URL).
TOKEN_SECRET_KEY = "token"
TLS_DIR = "/etc/netapp/tls"  # where a NetApp's certificate Secret (type kubernetes.io/tls) is mounted


def token_secret_name(netapp: str) -> str:
    return f"{netapp}-token"


def cluster_key_secret_name(netapp: str) -> str:
    return f"{netapp}-cluster-key"


# What a NetApp runs when its spec does not say.
NETAPP_PORT = DEFAULT_PORT
NETAPP_IMAGE = "ghcr.io/netapp-toolkit/netapp:0.1.0"
# curl with --max-time bounds a stalled download (KServe's storage initializer hangs forever); sha256sum comes
# from the image's busybox. The image runs as a non-root user.
MODEL_INIT_IMAGE = "curlimages/curl:8.11.1"
MODEL_CACHE_DIR = "/var/cache/netapp/models"  # on each node (a hostPath): the models its pods fetched, by sha256
# YOLOX-Nano (COCO, Apache-2.0): the model of a NetApp without one, of the catalogue's object-detection and of the demo.
DEFAULT_MODEL_URL = "https://github.com/Megvii-BaseDetection/YOLOX/releases/download/0.1.1rc0/yolox_nano.onnx"
DEFAULT_MODEL_SHA256 = "d39bee73564e338080378b0ad567fbb40e818b55bbfaf971de82a0267ed16b8a"
