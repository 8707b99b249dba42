# The control plane: `netapp operator` and `netapp middleware` (one image, two Deployments). Build from the root:
#   docker build -f docker/control-plane.Dockerfile -t ghcr.io/netapp-toolkit/control-plane:0.1.0 .
ARG PYTHON_IMAGE=python:3.11-slim-bookworm

FROM ${PYTHON_IMAGE} AS build
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY pyproject.toml README.md ./
COPY netapp ./netapp
COPY operator ./operator
# The same extras the tests install: pyproject.toml is the one requirements source.
RUN python -m venv /opt/venv \
    && /opt/venv/bin/pip install --upgrade pip \
    && /opt/venv/bin/pip install '.[operator,middleware]'

FROM ${PYTHON_IMAGE}
ENV PATH=/opt/venv/bin:$PATH PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 HOME=/tmp
RUN groupadd --gid 10001 netapp && useradd --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin netapp
COPY --from=build /opt/venv /opt/venv
USER 10001:10001
EXPOSE 8080
ENTRYPOINT ["netapp"]
CMD ["operator", "--all-namespaces"]
