"""Many replicas behind one Service: who owns a session (`ownership`), forwarding to the owner, draining, and
the 5G-ERA heartbeat to the middleware."""
