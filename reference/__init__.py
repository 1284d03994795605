"""Embree ground truth and metrics. Never imports gl_passes: the reference must be
independent of what it judges."""

#: Revision of the truth's definitions, recorded by the benchmarks that measure
#: against it (bench.sampling): 1, the first; 2, walks from one eye cast against
#: the faces front-facing from it (a back face met at the same distance as a front
#: face, at a silhouette edge, no longer hides it) and hits in a sample's own
#: plane are its own surface (reference.visibility).
REVISION = 2
