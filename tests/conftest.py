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


@pytest.fixture(scope="session")
def gbuffer_pass(gl):
    from gl_passes.gbuffer import GBufferPass

    with GBufferPass(gl) as p:
        yield p
