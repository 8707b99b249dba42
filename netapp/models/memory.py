"""A model's memory, bounded (`--max-model-memory`): onnxruntime's CPU arena is capped (and CUDA's, by its
`gpu_mem_limit`), so a graph that asks for more fails at once, before it touches the memory, and its first run (the
warm-up at load) refuses it in one line.

The arena is onnxruntime's environment allocator, one a process: every CPU session of the process (a rollout's
candidate beside the current model) draws from the one budget, set by the first model loaded."""

from __future__ import annotations

from typing import Any

from netapp.models.card import ModelRefused

DEFAULT_MAX_MODEL_MEMORY_MB = 1024  # the shared exports at 640 use 50 to 150 MB; the chart's netapp has 512 MB

_budget_mb: list[int] = []  # the budget registered in this process, once


def limit_memory(options: Any, budget_mb: int) -> int:
    """Caps the CPU arena of the sessions made with `options` (onnxruntime's SessionOptions) at `budget_mb` MiB (the
    process's first budget holds for all); returns the budget in force. 0 leaves onnxruntime's own arena, unbounded."""
    import onnxruntime as ort

    if budget_mb <= 0:
        return 0
    if not _budget_mb:
        info = ort.OrtMemoryInfo("Cpu", ort.OrtAllocatorType.ORT_ARENA_ALLOCATOR, 0, ort.OrtMemType.DEFAULT)
        ort.create_and_register_allocator(info, ort.OrtArenaCfg(budget_mb << 20, -1, -1, -1))
        _budget_mb.append(budget_mb)
    options.add_session_config_entry("session.use_env_allocators", "1")
    return _budget_mb[0]


def gpu_limited(providers: list[Any], budget_mb: int) -> list[Any]:
    """`providers` (onnxruntime's list: names, or (name, options)) with CUDA's arena capped at `budget_mb` MiB too
    (its `gpu_mem_limit`); the others as they are. 0 leaves them all as they are."""
    if budget_mb <= 0:
        return providers
    out: list[Any] = []
    for provider in providers:
        name, options = provider if isinstance(provider, tuple) else (provider, {})
        if name == "CUDAExecutionProvider":
            provider = (name, {**dict(options), "gpu_mem_limit": str(budget_mb << 20)})
        out.append(provider)
    return out


def first_run(run: Any, model: str, budget_mb: int) -> Any:
    """`run()`, the model's first inference; ModelRefused, one line, when it fails: over the memory budget (the arena
    said so), or any other way a graph can fail on its own input."""
    try:
        return run()
    except Exception as exc:  # onnxruntime's own exception types
        text = " ".join(str(exc).split())
        if budget_mb and ("Available memory of" in text or "bad_alloc" in text or "Failed to allocate" in text):
            raise ModelRefused(
                f"model {model} needs more than --max-model-memory {budget_mb} MB on its first run: give it more, "
                "or serve a smaller model or input size"
            ) from exc
        reason = text.split(" : ")[-1][:200]  # onnxruntime's message, after its "[ONNXRuntimeError] : 1 : FAIL :"
        raise ModelRefused(f"model {model} failed on its first run ({reason}): the graph cannot run") from exc
