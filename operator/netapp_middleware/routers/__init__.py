"""One router per concern; each is a thin layer over the registry, the catalogue and auth."""
