# The netapp server with onnxruntime's CUDA provider (falls back to the CPU without a GPU, and says which one it
# uses at start-up). Build from the repository root:
#   docker build -f docker/netapp-gpu.Dockerfile -t ghcr.io/netapp-toolkit/netapp:0.1.0-gpu .
ARG CUDA_IMAGE=nvidia/cuda:12.6.3-cudnn-runtime-ubuntu24.04

FROM ${CUDA_IMAGE} AS build
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 DEBIAN_FRONTEND=noninteractive
# hadolint ignore=DL3008
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 python3-venv \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY pyproject.toml README.md ./
COPY netapp ./netapp
COPY operator ./operator
# The tested install (`pip install '.[server,tracking]'`, and `trackers` without the opencv-python it asks for),
# then the same onnxruntime version in its CUDA build: the two wheels provide the same module, so one replaces the
# other.
RUN python3 -m venv /opt/venv \
    && /opt/venv/bin/pip install --upgrade pip \
    && /opt/venv/bin/pip install '.[server,tracking]' \
    && /opt/venv/bin/pip install --no-deps 'trackers>=2.6.1,<2.7' \
    && ORT_VERSION="$(/opt/venv/bin/python -c 'import importlib.metadata as m; print(m.version("onnxruntime"))')" \
    && /opt/venv/bin/pip uninstall -y onnxruntime \
    && /opt/venv/bin/pip install "onnxruntime-gpu==${ORT_VERSION}"
ARG MODEL_URL=""
ARG MODEL_SHA256=""
COPY docker/fetch_model.py /tmp/fetch_model.py
RUN mkdir -p /opt/model && if [ -n "$MODEL_URL" ]; then \
        /opt/venv/bin/python /tmp/fetch_model.py "$MODEL_URL" "$MODEL_SHA256" /opt/model/model.onnx; fi

FROM ${CUDA_IMAGE}
ENV PATH=/opt/venv/bin:$PATH PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 HOME=/tmp DEBIAN_FRONTEND=noninteractive
# hadolint ignore=DL3008
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 \
    && rm -rf /var/lib/apt/lists/* \
    && groupadd --gid 10001 netapp \
    && useradd --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin netapp
COPY --from=build /opt/venv /opt/venv
COPY --from=build /opt/model /opt/model
COPY docker/ort_provider.py /opt/netapp/ort_provider.py
COPY docker/netapp-gpu-entrypoint.sh /opt/netapp/entrypoint.sh
USER 10001:10001
EXPOSE 5896
ENTRYPOINT ["/opt/netapp/entrypoint.sh"]
CMD ["--host", "0.0.0.0", "--port", "5896"]
