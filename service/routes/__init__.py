"""One ``APIRouter`` per resource: service (health, readiness, metrics), scenes,
frames, reconstructions and depth-image sets. ``service.app.create_app`` includes them;
every router but the probes' requires the bearer token when one is set."""
