"""Model rollouts that judge themselves (docs/rollouts.md): a candidate model runs beside the current one on a sample
of frames (`shadow`), its answers are compared with the current model's (`compare`), and a verdict (`verdict`)
promotes it, in place, or rolls it back with the reason (`rollout`, the pipeline's `InferenceHook`); `netapp serve`'s
flags for it are `options`."""
