"""The tree stays ruff-clean (style rules in pyproject.toml)."""

from __future__ import annotations

import re
import subprocess
import sys

from tests.helpers import ROOT


def test_ruff_clean():
    out = subprocess.run([sys.executable, "-m", "ruff", "check", str(ROOT)], capture_output=True, text=True,
                         cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr


#: (pattern, the one module allowed to use it, the rule it keeps) over gl_passes/, service/ and bench/.
GL_RULES = (
    (r"\.use\(\s*location\s*=", "gl_passes/bindings.py", "texture units come from a unit table (bindings.Units)"),
    (r"\.read\(\s*size\s*=|\.read_into\(", "gl_passes/readback.py", "GL buffers are read back in one place"),
    (r"^\s*#version|gl_Position\s*=|gl_FragCoord", "gl_passes/shaders.py", "shaders live in gl_passes/shaders/"),
)


def test_gl_rules_hold_in_one_place():
    """The GL rules the guide sets (units from an allocator, read back in one place,
    no shader in a Python string), checked on the source: each pattern appears only
    in the one module that owns it."""
    offenders = []
    for path in sorted(p for d in ("gl_passes", "service", "bench") for p in (ROOT / d).rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        text = path.read_text()
        for pattern, owner, rule in GL_RULES:
            if rel != owner:
                offenders += [f"{rel}:{text[:m.start()].count(chr(10)) + 1}: {rule}"
                              for m in re.finditer(pattern, text, re.MULTILINE)]
    assert not offenders, "\n".join(offenders)
