"""Shared fixtures: one GL context for the test session (created on the main thread)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest_plugins = ("pytester",)

SHARED_SCENES = Path(os.environ.get("DEPTHVIEW_SHARED_SCENES",
                                    Path(__file__).resolve().parents[2] / "shared" / "scenes"))


@pytest.fixture(scope="session")
def gl():
    from gl_passes.context import create_gl_context

    ctx = create_gl_context()
    yield ctx
    ctx.release()


@pytest.fixture(scope="session")
def gbuffer_pass(gl):
    from gl_passes.gbuffer import GBufferPass

    p = GBufferPass(gl)
    yield p
    p.release()


def shared_scene(relpath: str) -> Path:
    """Path of a real model in ../shared/scenes; skips the test when absent."""
    p = SHARED_SCENES / relpath
    if not p.exists():
        pytest.skip(f"{p} not present")
    return p
