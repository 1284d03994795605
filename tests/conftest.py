"""Shared fixtures: one GL context for the test session (created on the main thread),
and pytester for the plugin's own tests. Test modules import helpers from
tests/helpers.py, never from this file (pytest loads it under its own name)."""

from __future__ import annotations

import pytest

pytest_plugins = ("pytester",)


@pytest.fixture(scope="session")
def gl():
    from gl_passes.context import create_gl_context

    ctx = create_gl_context()
    yield ctx
    ctx.release()


@pytest.fixture(autouse=True)
def _no_gl_error(request):
    """A test that uses the session's context leaves no GL error behind (glGetError
    holds the first until read, so it names the test that caused it)."""
    yield
    if "gl" in request.fixturenames:
        error = request.getfixturevalue("gl").ctx.error
        assert error == "GL_NO_ERROR", f"{request.node.nodeid} left {error} on the session's GL context"


@pytest.fixture(scope="session")
def gbuffer_pass(gl):
    from gl_passes.gbuffer import GBufferPass

    with GBufferPass(gl) as p:
        yield p
