"""The layering DESIGN.md states ("Dependencies point one way"), checked on the
source: `gl_passes` and `reference` never import each other, `scenes` imports
neither (nor the service), and nothing below `service` imports it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.helpers import ROOT

#: package → top-level packages of ours it must never import
FORBIDDEN = {
    "gl_passes": {"reference", "service", "bench", "tests"},
    "reference": {"gl_passes", "service", "bench", "tests"},
    "scenes": {"gl_passes", "reference", "service", "bench", "tests"},
    "service": {"bench", "tests"},
}


def imported_modules(path: Path) -> set[str]:
    """Every module name a source file imports (absolute imports, any nesting depth)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_imports_point_one_way(package):
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for name in imported_modules(path):
            if name.split(".")[0] in FORBIDDEN[package]:
                bad.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not bad, "\n".join(bad)


def test_tests_share_helpers_not_each_other():
    """Test modules import shared builders from tests.helpers (under that one
    name), never another test module nor conftest (which pytest imports itself)."""
    ours = {p.stem for p in (ROOT / "tests").glob("*.py")}
    bad = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        for name in imported_modules(path):
            last = name.split(".")[-1]
            if last == "conftest" or last.startswith("test_") or (last in ours and not name.startswith("tests.")):
                bad.append(f"{path.name} imports {name}")
    assert not bad, "\n".join(bad)


def test_bench_runs_as_modules_without_import_cycles():
    """bench/ scripts run as `python -m bench.<name>`: no sys.path edits, and the
    imports between bench modules (at any depth, lazy ones included) form no cycle."""
    graph: dict[str, set[str]] = {}
    hacks = []
    for path in sorted((ROOT / "bench").glob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        if any(isinstance(n, ast.Attribute) and n.attr == "path" and isinstance(n.value, ast.Name)
               and n.value.id == "sys" for n in ast.walk(tree)):
            hacks.append(path.name)
        graph[path.stem] = {m.split(".")[1] for m in imported_modules(path) if m.startswith("bench.")}
    assert not hacks, f"sys.path edited in {hacks}"

    def cycle_from(node: str, stack: list[str]) -> list[str] | None:
        if node in stack:
            return stack[stack.index(node):] + [node]
        for nxt in sorted(graph.get(node, ())):
            found = cycle_from(nxt, stack + [node])
            if found:
                return found
        return None

    cycles = [c for c in (cycle_from(n, []) for n in graph) if c]
    assert not cycles, " → ".join(cycles[0])
