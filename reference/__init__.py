"""Embree ground truth and metrics. Never imports gl_passes: the reference must be
independent of what it judges."""
