"""GLSL source loading: `#include "file.glsl"` and #defines injected after #version.

Shaders live in gl_passes/shaders/*.glsl (and .vert/.geom/.frag/.comp); programs
are compiled once per GL context and cached on it.
"""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

import moderngl

from gl_passes.context import GLContext
from scenes.shading import glsl_defines

SHADER_DIR = Path(__file__).parent / "shaders"
_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$', re.MULTILINE)


@cache
def _read(name: str) -> str:
    return (SHADER_DIR / name).read_text()


def shader_source(name: str, defines: dict[str, str] | None = None) -> str:
    """Source of shaders/`name` with includes expanded and defines (plus the
    shading constants) inserted after the #version line."""

    def expand(text: str, depth: int = 0) -> str:
        if depth > 8:
            raise ValueError(f"include nesting too deep in {name}")
        return _INCLUDE.sub(lambda m: expand(_read(m.group(1)), depth + 1), text)

    src = expand(_read(name))
    allv = {**glsl_defines(), **(defines or {})}
    head, _, body = src.partition("\n")
    if not head.startswith("#version"):
        raise ValueError(f"{name} must start with #version")
    lines = "".join(f"#define {k} {v}\n" for k, v in allv.items())
    return f"{head}\n{lines}#line 2\n{body}"


def program(gl: GLContext, vertex: str, fragment: str | None = None, geometry: str | None = None,
            defines: dict[str, str] | None = None, varyings: tuple[str, ...] = ()) -> moderngl.Program:
    """Compiled program for the named shader files, cached on `gl`."""
    gl.check_thread()
    key = (vertex, fragment, geometry, tuple(sorted((defines or {}).items())), varyings)
    cache = gl.programs
    if key not in cache:
        cache[key] = gl.ctx.program(
            vertex_shader=shader_source(vertex, defines),
            fragment_shader=shader_source(fragment, defines) if fragment else None,
            geometry_shader=shader_source(geometry, defines) if geometry else None,
            varyings=varyings,
        )
    return cache[key]


def compute_program(gl: GLContext, name: str, defines: dict[str, str] | None = None) -> moderngl.ComputeShader:
    """Compiled compute shader, cached on `gl`."""
    gl.check_thread()
    key = ("compute", name, tuple(sorted((defines or {}).items())))
    cache = gl.programs
    if key not in cache:
        cache[key] = gl.ctx.compute_shader(shader_source(name, defines))
    return cache[key]
