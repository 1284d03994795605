"""depthview HTTP service: FastAPI app, content-addressed scene store, GL render worker, CLI."""
