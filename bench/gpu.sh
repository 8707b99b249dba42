#!/usr/bin/env bash
# The prepared GPU run (issue 34): a venv from PyPI on a bare GPU machine, then in one go (under 8 minutes):
#   1. the model's own time by provider (CPU, CUDA, TensorRT FP16; batch 1 and 8): bench/providers.py, for
#      YOLOX-Nano and the shared YOLO11 exports where they are;
#   2. the time outside the model for frames, Socket.IO and HTTP: bench/transports.py;
#   3. results/s, p50 and p95 for 1, 8 and 32 robots, batching across robots (a batch-dynamic YOLOX-Nano, batched
#      and not, side by side): bench/robots.py with one replica.
# From the repository root, with ../shared beside it (or MODEL=, VIDEO=, EXPORTS=):
#   bench/gpu.sh                                  # set up .venv-gpu from PyPI, then run on the GPU
#   DEVICE=tensorrt FP16=1 bench/gpu.sh           # the netapps on TensorRT FP16 (a netapp with --device)
#   WHEELS=/path/to/wheels bench/gpu.sh           # no registry: install from a folder of wheels
#   PYTHON=.venv/bin/python DEVICE=cpu QUICK=1 bench/gpu.sh   # no set-up; the CPU provider, a few seconds a step
# Output: results/gpu-<time>/ (summary.md: the machine, the load, each step's table; each step's own folder).
# docs/benchmarks.md#the-gpu-run says what a GPU session runs and what came out.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
SHARED=${SHARED:-$ROOT/../shared}
MODEL=${MODEL:-$SHARED/models/yolox_nano.onnx}
VIDEO=${VIDEO:-$SHARED/media/pedestrians.avi}
EXPORTS=${EXPORTS:-$SHARED/models/exports}
DEVICE=${DEVICE:-auto}        # the netapps' --device (auto, cuda, tensorrt, cpu) where `netapp serve` has it
FP16=${FP16:-}                # 1: --fp16 for the netapps
QUICK=${QUICK:-}              # 1: a few seconds a step (the CPU check of this script)
VENV=${VENV:-$ROOT/.venv-gpu}
OUT=${OUT:-$ROOT/results/gpu-$(date -u +%Y%m%d-%H%M%S)}

# Each step's size (any of them can be set): model runs a provider row, seconds a transport or robots row, robots.
if [ -n "$QUICK" ]; then
    : "${RUNS:=20}" "${DURATION:=3}" "${WARMUP:=1}" "${MAX_DURATION:=2}" "${ROBOTS:=1,8}"
else
    : "${RUNS:=300}" "${DURATION:=10}" "${WARMUP:=4}" "${MAX_DURATION:=6}" "${ROBOTS:=1,8,32}"
fi
for f in "$MODEL" "$VIDEO"; do
    [ -f "$f" ] || { echo "gpu.sh: $f is missing: set MODEL= and VIDEO= (the shared ones live in ../shared)" >&2; exit 2; }
done

# --- the venv: the server's requirements with onnxruntime's CUDA build in place of onnxruntime (the same module),
# NVIDIA's CUDA and cuDNN wheels (onnxruntime-gpu's own extras), TensorRT's where NVIDIA's index is reachable.
if [ -z "${PYTHON:-}" ]; then
    PYTHON=$VENV/bin/python
    if [ ! -x "$PYTHON" ]; then
        python3 -m venv ${SYSTEM_SITE:+--system-site-packages} "$VENV"
        pip=("$PYTHON" -m pip install -q ${WHEELS:+--no-index --find-links "$WHEELS"})
        if [ "$DEVICE" = cpu ]; then
            python3 docker/requirements.py pyproject.toml --core server bench > "$VENV/requirements.txt"
        else
            python3 docker/requirements.py pyproject.toml --core --without=onnxruntime server gpu bench \
                > "$VENV/requirements.txt"
        fi
        "${pip[@]}" -r "$VENV/requirements.txt" onnx
        if [ "$DEVICE" != cpu ]; then  # optional: a placeholder on PyPI that fetches from NVIDIA's own index
            python3 docker/requirements.py pyproject.toml tensorrt | xargs "${pip[@]}" \
                || echo "gpu.sh: no TensorRT libraries (NVIDIA's index unreachable?): its rows will say so" >&2
        fi
    fi
fi
export PYTHONPATH=$ROOT${PYTHONPATH:+:$PYTHONPATH}
mkdir -p "$OUT"
SUMMARY=$OUT/summary.md
SERVE_ARGS=""
if "$PYTHON" -m netapp serve --help 2>/dev/null | grep -q -- '--device'; then
    SERVE_ARGS="--device $DEVICE${FP16:+ --fp16}"
    if [ "$DEVICE" = tensorrt ] || [ "$DEVICE" = auto ]; then SERVE_ARGS="$SERVE_ARGS --trt-cache $OUT/trt-cache"; fi
fi
DEVICES=cpu,cuda,tensorrt-fp16
[ "$DEVICE" = cpu ] && DEVICES=cpu
MODELS=$MODEL
for export in yolo11n.onnx yolo11n-seg.onnx yolo11n-pose.onnx; do
    [ -f "$EXPORTS/$export" ] && MODELS=$MODELS,$EXPORTS/$export
done

{
    echo "# GPU run $(date -u +%Y-%m-%dT%H:%M:%SZ)"
    echo
    echo '```'
    uptime
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
    "$PYTHON" -c 'import onnxruntime as o, sys; print(sys.version.split()[0], "onnxruntime", o.__version__, o.get_available_providers())'
    "$PYTHON" -c 'from netapp.models.providers import preload; print(preload().describe())'
    echo "netapp serve $SERVE_ARGS (DEVICE=$DEVICE; the netapp picks CUDA where onnxruntime offers it without --device)"
    echo '```'
} > "$SUMMARY"
cat "$SUMMARY"
started=$(date +%s)

step() {  # step NAME COMMAND...: run it with a limit, its output in OUT/NAME.log, its table into the summary
    local name=$1; shift
    echo "== $name" >&2
    local t0; t0=$(date +%s)
    set +e
    timeout "${STEP_LIMIT:-300}" "$@" > "$OUT/$name.log" 2>&1
    local rc=$?
    set -e
    { echo; echo "## $name ($(( $(date +%s) - t0 )) s, exit $rc, load $(cut -d' ' -f1-3 /proc/loadavg))"; echo;
      grep '^|' "$OUT/$name.log" || tail -5 "$OUT/$name.log"; } >> "$SUMMARY"
}

step providers "$PYTHON" -m bench.providers --models "$MODELS" --devices "$DEVICES" --batches 1,8 \
    --runs "$RUNS" --warmup 10 --trt-cache "$OUT/trt-cache" --json "$OUT/providers.json"
step transports "$PYTHON" -m bench.transports --model "$MODEL" --video "$VIDEO" --fps 25 \
    --transports direct,frames,ws,http --duration "$DURATION" --warmup "$WARMUP" --serve-args "$SERVE_ARGS" \
    --out "$OUT"
# Batching across robots needs a model whose batch is free: YOLOX-Nano's graph allows it (bench/providers.py).
BATCHED=$OUT/yolox_nano-dynamic.onnx
"$PYTHON" -m bench.providers --make-dynamic "$MODEL" --out "$BATCHED" >/dev/null || BATCHED=$MODEL
step robots "$PYTHON" -m bench.robots --model "$BATCHED" --video "$VIDEO" --robots "$ROBOTS" --replicas 1 \
    --no-balancer --duration "$DURATION" --max-duration "$MAX_DURATION" \
    --variants "batched=$SERVE_ARGS;unbatched=--max-batch 1 $SERVE_ARGS" --out "$OUT"

echo >> "$SUMMARY"
echo "All steps: $(( $(date +%s) - started )) s." >> "$SUMMARY"
cat "$SUMMARY"
