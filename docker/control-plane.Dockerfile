# The control plane: `netapp operator` and `netapp middleware` (one image, two Deployments), without the netapp's
# inference stack (no process of theirs imports numpy, OpenCV or onnxruntime). `make images` builds it
# (docs/images.md); by hand, from the repository root:
#   docker build -f docker/control-plane.Dockerfile -t ghcr.io/netapp-toolkit/control-plane:0.1.0 .
# Layers, bottom up: the base, the dependencies (from pyproject.toml alone), the code. A TLS-intercepting proxy's CA
# goes in as the secret `ca`.
# PYTHON_IMAGE is the images' base, BUILD_IMAGE the build stages' (the same Python at the same path, plus pip; with
# binutils the build strips debug sections): `make images` makes both from Debian with mmdebstrap.
ARG PYTHON_IMAGE=python:3.11-slim-bookworm
ARG BUILD_IMAGE=python:3.11-slim-bookworm

FROM ${BUILD_IMAGE} AS requirements
COPY pyproject.toml docker/requirements.py /src/
# `tracing` (OpenTelemetry, about 9 MB): the deployments' and reconciles' spans, off until OTEL_* variables say.
RUN python3 /src/requirements.py /src/pyproject.toml operator middleware tracing > /src/control-plane.txt

# pip, setuptools and the layer tool stay in this stage: they install into /opt/venv from outside it.
FROM ${BUILD_IMAGE} AS pip
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_CERT=/etc/ssl/certs/ca-certificates.crt
RUN --mount=type=secret,id=ca,target=/etc/ssl/certs/ca-certificates.crt \
    python3 -m venv /opt/pip && /opt/pip/bin/pip install --upgrade 'pip>=24' 'setuptools>=77' wheel
COPY docker/layer.py docker/slim-packages.sh /opt/pip/

FROM pip AS deps
COPY --from=requirements /src/control-plane.txt /tmp/
RUN --mount=type=secret,id=ca,target=/etc/ssl/certs/ca-certificates.crt \
    python3 -m venv --without-pip /opt/venv \
    && /opt/pip/bin/pip --python /opt/venv/bin/python install -r /tmp/control-plane.txt \
    && /opt/pip/bin/pip --python /opt/venv/bin/python check \
    && printf '/opt/app\n' > "$(echo /opt/venv/lib/python3*/site-packages)/netapp-layers.pth" \
    && /opt/pip/slim-packages.sh "$(echo /opt/venv/lib/python3*/site-packages)"

# The project's own code, without its dependencies (the layer below has them).
FROM deps AS code
WORKDIR /src
COPY pyproject.toml README.md ./
COPY netapp ./netapp
COPY operator ./operator
RUN /opt/pip/bin/pip wheel --no-deps --no-build-isolation --wheel-dir /tmp/wheel . \
    && /opt/pip/bin/python /opt/pip/layer.py /opt/venv /opt/app --no-deps /tmp/wheel/*.whl

FROM ${PYTHON_IMAGE}
ENV PATH=/opt/app/bin:/opt/venv/bin:$PATH PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 HOME=/tmp
RUN groupadd --gid 10001 netapp && useradd --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin netapp
COPY --from=deps /opt/venv /opt/venv
COPY --from=code /opt/app /opt/app
USER 10001:10001
EXPOSE 8080
ENTRYPOINT ["netapp"]
CMD ["operator", "--all-namespaces"]
