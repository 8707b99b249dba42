"""HTTP: the paper's REST transport, health, metrics and Open Inference Protocol v2 endpoints, over the dataplane."""
