# The netapp server (CPU, onnxruntime), and with --target netapp-tracking the same plus the tracker's libraries.
# `make images` builds both (docs/images.md); by hand, from the repository root:
#   docker build -f docker/netapp.Dockerfile -t ghcr.io/netapp-toolkit/netapp:0.1.0 .
#   docker build -f docker/netapp.Dockerfile --target netapp-tracking -t ghcr.io/netapp-toolkit/netapp:0.1.0-tracking .
#   docker build -f docker/netapp.Dockerfile --build-arg H264=1 -t ghcr.io/netapp-toolkit/netapp:0.1.0-h264 .
#   docker build -f docker/netapp.Dockerfile --build-arg WEBRTC=1 -t ghcr.io/netapp-toolkit/netapp:0.1.0-webrtc .
#   docker build -f docker/netapp.Dockerfile --target netapp-gpu -t ghcr.io/netapp-toolkit/netapp:0.1.0-gpu .
# The GPU target is onnxruntime's CUDA build with NVIDIA's CUDA and cuDNN wheels on the same Debian base (the node
# brings the driver alone); --build-arg TENSORRT=1 adds TensorRT's, --build-arg GPU_CONSTRAINTS=onnxruntime-gpu==1.26.0
# the CUDA 12 build for drivers older than CUDA 13's (docs/images.md#the-gpu-image).
# Bake a model in only when asked (otherwise the operator's init container or a volume provides it):
#   --build-arg MODEL_URL=https://.../yolox_nano.onnx --build-arg MODEL_SHA256=<hex>
# Layers, bottom up: the base, the dependencies (from pyproject.toml alone), [the tracker's], the model, the code: a
# change to the code rebuilds the top layer only. A TLS-intercepting proxy's CA goes in as the secret `ca`.
# PYTHON_IMAGE is the images' base, BUILD_IMAGE the build stages' (the same Python at the same path, plus pip; with
# binutils the build strips debug sections): `make images` makes both from Debian with mmdebstrap.
ARG PYTHON_IMAGE=python:3.11-slim-bookworm
ARG BUILD_IMAGE=python:3.11-slim-bookworm

FROM ${BUILD_IMAGE} AS requirements
# --build-arg H264=1 adds PyAV (the `h264` extra, about 100 MB): without it the netapp serves the http and ws
# transports and refuses H.264 streams with `h264_unavailable` and the install hint. The `tracing` extra
# (OpenTelemetry, about 7 MB: protobuf comes with onnxruntime) is always in; it stays off until OTEL_* variables say.
# So is `broker` (aio-pika, aiomqtt, confluent-kafka: a NetApp's spec.publish, docs/broker.md).
ARG H264=""
# --build-arg WEBRTC=1 adds aiortc (the `webrtc` extra: /camera and POST /webrtc/offer), with PyAV: about 134 MB, 30
# of them aiortc's own (cryptography, libsrtp, dnspython); without it the routes answer with the install hint.
ARG WEBRTC=""
ARG TENSORRT=""
COPY pyproject.toml docker/requirements.py /src/
RUN python3 /src/requirements.py /src/pyproject.toml --core server tracing broker ${H264:+h264} ${WEBRTC:+webrtc} \
        > /src/server.txt \
    && python3 /src/requirements.py /src/pyproject.toml --core --without=onnxruntime \
        server tracing gpu broker ${TENSORRT:+tensorrt} > /src/gpu.txt \
    && python3 /src/requirements.py /src/pyproject.toml tracking-runtime > /src/tracking.txt \
    && python3 /src/requirements.py /src/pyproject.toml --direct tracking > /src/tracking-no-deps.txt

# pip, setuptools and the layer tool stay in this stage: they install into /opt/venv from outside it.
FROM ${BUILD_IMAGE} AS pip
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_CERT=/etc/ssl/certs/ca-certificates.crt
RUN --mount=type=secret,id=ca,target=/etc/ssl/certs/ca-certificates.crt \
    python3 -m venv /opt/pip && /opt/pip/bin/pip install --upgrade 'pip>=24' 'setuptools>=77' wheel
COPY docker/layer.py docker/slim-packages.sh /opt/pip/

FROM pip AS deps
COPY --from=requirements /src/server.txt /tmp/
RUN --mount=type=secret,id=ca,target=/etc/ssl/certs/ca-certificates.crt \
    python3 -m venv --without-pip /opt/venv \
    && /opt/pip/bin/pip --python /opt/venv/bin/python install -r /tmp/server.txt \
    && /opt/pip/bin/pip --python /opt/venv/bin/python check \
    && printf '/opt/tracking\n/opt/app\n' > "$(echo /opt/venv/lib/python3*/site-packages)/netapp-layers.pth" \
    && /opt/pip/slim-packages.sh "$(echo /opt/venv/lib/python3*/site-packages)"

# The GPU build's dependencies: the server's, with onnxruntime-gpu and NVIDIA's wheels in place of onnxruntime (the
# same module). GPU_CONSTRAINTS (space-separated pip constraints) pins versions, e.g. the CUDA 12 build.
FROM pip AS gpu-deps
ARG GPU_CONSTRAINTS=""
COPY --from=requirements /src/gpu.txt /tmp/
RUN --mount=type=secret,id=ca,target=/etc/ssl/certs/ca-certificates.crt \
    printf '%s\n' ${GPU_CONSTRAINTS} > /tmp/constraints.txt \
    && python3 -m venv --without-pip /opt/venv \
    && /opt/pip/bin/pip --python /opt/venv/bin/python install -r /tmp/gpu.txt -c /tmp/constraints.txt \
    && /opt/pip/bin/pip --python /opt/venv/bin/python check \
    && printf '/opt/app\n' > "$(echo /opt/venv/lib/python3*/site-packages)/netapp-layers.pth" \
    && /opt/pip/slim-packages.sh "$(echo /opt/venv/lib/python3*/site-packages)"

# The tracker: `trackers` and `supervision` without the dependency lists they declare (opencv-python, which would
# clash with opencv-python-headless, plotting and video libraries no netapp process imports), and what they import.
FROM deps AS tracking
COPY --from=requirements /src/tracking.txt /src/tracking-no-deps.txt /tmp/
RUN --mount=type=secret,id=ca,target=/etc/ssl/certs/ca-certificates.crt \
    /opt/pip/bin/python /opt/pip/layer.py /opt/venv /opt/tracking -r /tmp/tracking.txt \
    && /opt/pip/bin/python /opt/pip/layer.py /opt/venv /opt/tracking --no-deps -r /tmp/tracking-no-deps.txt \
    && /opt/pip/bin/python /opt/pip/layer.py /opt/venv /opt/tracking --no-deps 'trackers>=2.6.1,<2.7' \
    && /opt/pip/slim-packages.sh /opt/tracking \
    && (/opt/pip/bin/pip --python /opt/venv/bin/python check > /tmp/check.txt || true) \
    && ! grep 'has requirement' /tmp/check.txt  # the left-out ones are missing; a wrong version fails

FROM pip AS model
ARG MODEL_URL=""
ARG MODEL_SHA256=""
COPY docker/fetch_model.py /tmp/fetch_model.py
RUN --mount=type=secret,id=ca,target=/etc/ssl/certs/ca-certificates.crt \
    mkdir -p /opt/model && if [ -n "$MODEL_URL" ]; then \
        python3 /tmp/fetch_model.py "$MODEL_URL" "$MODEL_SHA256" /opt/model/model.onnx; fi

# The project's own code, without its dependencies (the layers below have them).
FROM deps AS code
WORKDIR /src
COPY pyproject.toml README.md ./
COPY netapp ./netapp
COPY operator ./operator
RUN /opt/pip/bin/pip wheel --no-deps --no-build-isolation --wheel-dir /tmp/wheel . \
    && /opt/pip/bin/python /opt/pip/layer.py /opt/venv /opt/app --no-deps /tmp/wheel/*.whl

FROM ${PYTHON_IMAGE} AS runtime
ENV PATH=/opt/app/bin:/opt/venv/bin:$PATH PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 HOME=/tmp
RUN groupadd --gid 10001 netapp && useradd --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin netapp
EXPOSE 5896
ENTRYPOINT ["netapp", "serve"]
CMD ["--host", "0.0.0.0", "--port", "5896"]

FROM runtime AS netapp-tracking
COPY --from=deps /opt/venv /opt/venv
COPY --from=tracking /opt/tracking /opt/tracking
COPY --from=model /opt/model /opt/model
COPY --from=code /opt/app /opt/app
USER 10001:10001

# The GPU netapp: `netapp serve` loads the CUDA, cuDNN (and TensorRT) libraries from the wheels and says which
# (netapp.models.providers.preload); without a GPU it serves on the CPU and says why.
FROM runtime AS netapp-gpu
COPY --from=gpu-deps /opt/venv /opt/venv
COPY --from=model /opt/model /opt/model
COPY --from=code /opt/app /opt/app
USER 10001:10001

# The default target. No compiler or pip came along; nothing is written outside /tmp, so a read-only root works.
FROM runtime AS netapp
COPY --from=deps /opt/venv /opt/venv
COPY --from=model /opt/model /opt/model
COPY --from=code /opt/app /opt/app
USER 10001:10001

