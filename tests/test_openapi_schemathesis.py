"""Issue 15, done-when: a schemathesis run over the whole OpenAPI document finds no 5xx
and no schema violation.

Every operation of the service's OpenAPI document gets schemathesis's example, coverage
and fuzzing phases — valid and invalid requests — against the real server (uvicorn as
``depthview serve`` runs it, with its render worker process), and every response is
checked: no 5xx (``not_a_server_error``: 503 and 504 count, so one client must never hit
the bounded queue or the job timeout), a documented status code, a documented content
type, a body matching the documented schema, documented headers matching theirs.

Path ``scene_id``\\ s are drawn from what schemathesis generates and from real scenes (the
built-in cornell default and a small upload; DELETE deletes an upload of its own, so the
renders keep theirs), and a render body that names no size also
comes with a small one, so the render endpoints render (the run checks they did). The
service runs with small frame limits (64 px a side, which the document states) and a small
memory budget, so random cameras, effects, sample counts and resolutions either render
fast or are refused with their documented 422. Deterministic (seeded per operation): CI
runs the same cases every time. A second, shorter run sets a bearer token and sends none:
every protected operation answers its documented 401.
"""

from __future__ import annotations

import collections
import contextlib
from collections.abc import Iterator

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from service.store import builtin_id
from tests.helpers import live_server, obj_text, wait_ready

#: Checks every response gets.
CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance,
          response_headers_conformance]
#: Service limits of the run: random requests render fast or get their documented 422.
LIMITS = {"max_width": 64, "max_height": 64, "max_pixels": 64 * 64, "max_job_bytes": 96 * 2**20,
          "job_timeout_s": 60.0, "max_upload_bytes": 64 * 1024}
#: Fuzzed cases per operation (the coverage phase adds its own, about as many again).
MAX_EXAMPLES = 150
TOKEN = "schemathesis-token"
RENDERS = ("POST /scenes/{scene_id}/frames", "POST /scenes/{scene_id}/reconstruction",
           "POST /scenes/{scene_id}/depth-images")

#: Real scenes the path parameter is drawn from besides generated ids: the cornell default and
#: (added by the `live` fixture) a small upload.
SCENE_IDS = [builtin_id("cornell")]
#: The scenes DELETE draws from besides generated ids: a second upload of its own (added by
#: the `live` fixture), so that deleting a real scene is run without taking the renders' away.
DELETE_IDS: list[str] = []
#: Small sizes a render request gets where it names none (the defaults, 512, are over LIMITS).
SMALL_SIZES = {"frames": {"width": 48, "height": 32}, "depth-images": {"width": 32, "height": 32},
               "reconstruction": {"resolution": 32}}
#: (operation, status) → responses seen (the runs record them; test_the_run_rendered reads them).
SEEN: collections.Counter[tuple[str, int]] = collections.Counter()


def openapi_document() -> dict:
    """The service's OpenAPI document with LIMITS (what its GET /openapi.json serves)."""
    from service.app import create_app
    from service.config import Settings

    return create_app(Settings(**LIMITS)).openapi()


schema = schemathesis.openapi.from_dict(openapi_document())
schema.config.phases.update(phases=["examples", "coverage", "fuzzing"])
schema.config.generation.update(max_examples=MAX_EXAMPLES, deterministic=True)


@schema.hook
def flatmap_path_parameters(context, path_parameters):
    """A generated scene id, or one of the real scenes (so renders render; DELETE gets its own)."""
    if "scene_id" not in (path_parameters or {}):
        return st.just(path_parameters)
    ids = DELETE_IDS if context.operation.method.upper() == "DELETE" else SCENE_IDS
    return st.sampled_from([path_parameters, *({**path_parameters, "scene_id": s} for s in ids)])


@schema.hook
def flatmap_body(context, body):
    """A generated body, or for a render the same body with a small size where it names none."""
    sizes = SMALL_SIZES.get(context.operation.path.rsplit("/", 1)[-1])
    if sizes is None or not isinstance(body, dict):
        return st.just(body)
    return st.sampled_from([body, {**sizes, **body}])


@schema.hook
def after_call(context, case, response):
    SEEN[(case.operation.label, response.status_code)] += 1


@contextlib.contextmanager
def serve(tmp_path_factory, **overrides) -> Iterator[str]:
    """The service with LIMITS on a loopback port, ready (its base URL)."""
    with live_server(tmp_path_factory.mktemp("data"), **LIMITS, **overrides) as (host, port):
        base = f"http://{host}:{port}"
        with httpx.Client(base_url=base) as client:
            wait_ready(client, timeout=120)
        assert httpx.get(f"{base}/openapi.json").json() == schema.raw_schema, "the served document differs"
        yield base


@pytest.fixture(scope="module")
def live(tmp_path_factory) -> Iterator[str]:
    """The service (base URL), with a small uploaded scene among SCENE_IDS and another
    one in DELETE_IDS."""
    with serve(tmp_path_factory) as base:
        for ids, quads in ((SCENE_IDS, 3), (DELETE_IDS, 2)):
            r = httpx.post(f"{base}/scenes?format=obj", content=obj_text(quads), timeout=60,
                           headers={"content-type": "application/octet-stream"})
            assert r.status_code in (200, 201), r.text
            ids.append(r.json()["id"])
        yield base
        SCENE_IDS.pop()
        DELETE_IDS.pop()


@pytest.fixture(scope="module")
def live_with_token(tmp_path_factory) -> Iterator[str]:
    with serve(tmp_path_factory, token=TOKEN) as base:
        yield base


@schema.parametrize()
@settings(deadline=None, suppress_health_check=list(HealthCheck), max_examples=MAX_EXAMPLES)
def test_every_operation_conforms_to_the_openapi_document(case, live):
    case.call_and_validate(base_url=live, checks=CHECKS, timeout=120)


@schema.parametrize()
@settings(deadline=None, suppress_health_check=list(HealthCheck), max_examples=10)
def test_without_the_token_every_operation_conforms_too(case, live_with_token):
    response = case.call_and_validate(base_url=live_with_token, checks=CHECKS, timeout=120)
    if case.operation.path not in ("/healthz", "/readyz") and response.status_code < 300:
        raise AssertionError(f"{case.operation.label} answered {response.status_code} without the token")


def test_the_run_covers_every_operation():
    """The document the runs walk has every HTTP operation of the service."""
    ops = {f"{r.ok().method.upper()} {r.ok().path}" for r in schema.get_all_operations()}
    assert ops == {
        "GET /healthz", "GET /readyz", "GET /metrics", "GET /client", "GET /scenes", "POST /scenes",
        "GET /scenes/{scene_id}", "DELETE /scenes/{scene_id}", *RENDERS}


def test_the_run_rendered():
    """The conformance run was not vacuous: every render operation rendered (200) several
    times and refused invalid requests (422). Reads what the runs above recorded."""
    if not any(op in RENDERS for op, _ in SEEN):
        pytest.skip("the schemathesis runs did not run in this session")
    for op in RENDERS:
        assert SEEN[(op, 200)] >= 5 and SEEN[(op, 422)] >= 5, {k: v for k, v in SEEN.items() if k[0] == op}
    assert SEEN[("POST /scenes", 201)] + SEEN[("POST /scenes", 200)] >= 1
    assert SEEN[("DELETE /scenes/{scene_id}", 204)] + SEEN[("DELETE /scenes/{scene_id}", 200)] >= 1
