"""How a running netapp loads a candidate model: the processor it serves, made again with another model file."""

from __future__ import annotations

from dataclasses import replace

from netapp.models.detector import DetectorConfig
from netapp.sdk.processor import Processor
from netapp.server.rollout.rollout import CandidateFactory

CANDIDATE_DOWNLOAD_TIMEOUT_S = 60.0


def candidate_factory(processor: Processor) -> CandidateFactory | None:
    """A factory of candidates like `processor` (its class and options, another model), loaded; None for a
    processor that loads its own weights (it has no model file to change)."""
    config = getattr(processor, "config", None)
    if not isinstance(config, DetectorConfig):
        return None
    cls = type(processor)

    def load(model: str, sha256: str | None) -> Processor:
        from netapp.models.source import resolve_model

        path = resolve_model(
            model, sha256, timeout_s=CANDIDATE_DOWNLOAD_TIMEOUT_S, option="candidate", what="the candidate"
        )
        candidate = cls(replace(config, model_path=str(path)))  # type: ignore[call-arg]
        candidate.load()
        return candidate

    return load
