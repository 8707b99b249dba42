# The netapp server (CPU, onnxruntime). Build from the repository root:
#   docker build -f docker/netapp.Dockerfile -t ghcr.io/netapp-toolkit/netapp:0.1.0 .
# Bake a model in only when asked (otherwise the operator's init container or a volume provides it):
#   --build-arg MODEL_URL=https://.../yolox_nano.onnx --build-arg MODEL_SHA256=<hex>
ARG PYTHON_IMAGE=python:3.11-slim-bookworm

FROM ${PYTHON_IMAGE} AS build
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY pyproject.toml README.md ./
COPY netapp ./netapp
COPY operator ./operator
# The same install as the tests (`pip install '.[server,tracking]'`, and `trackers` without the opencv-python it
# asks for, which would clash with opencv-python-headless): pyproject.toml is the one requirements source.
RUN python -m venv /opt/venv \
    && /opt/venv/bin/pip install --upgrade pip \
    && /opt/venv/bin/pip install '.[server,tracking]' \
    && /opt/venv/bin/pip install --no-deps 'trackers>=2.6.1,<2.7'
ARG MODEL_URL=""
ARG MODEL_SHA256=""
COPY docker/fetch_model.py /tmp/fetch_model.py
RUN mkdir -p /opt/model && if [ -n "$MODEL_URL" ]; then \
        python /tmp/fetch_model.py "$MODEL_URL" "$MODEL_SHA256" /opt/model/model.onnx; fi

FROM ${PYTHON_IMAGE}
ENV PATH=/opt/venv/bin:$PATH PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 HOME=/tmp
RUN groupadd --gid 10001 netapp && useradd --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin netapp
COPY --from=build /opt/venv /opt/venv
COPY --from=build /opt/model /opt/model
# No compiler or pip cache came along; nothing is written outside /tmp, so a read-only root file system works.
USER 10001:10001
EXPOSE 5896
ENTRYPOINT ["netapp", "serve"]
CMD ["--host", "0.0.0.0", "--port", "5896"]
