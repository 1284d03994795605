"""Issue 15, item 7: the Docker images install what `make serve` installs. The images are
built by `make docker-test` (not in the default suite); these checks read the files, so
the two images cannot drift apart nor away from the Makefile's recipes."""

from __future__ import annotations

import re

from tests.helpers import ROOT

DOCKERFILES = ("Dockerfile.cpu", "Dockerfile.nvidia")


def instructions(name: str) -> list[str]:
    """The Dockerfile's instructions, continuation lines joined, comments dropped."""
    text = (ROOT / "docker" / name).read_text()
    text = re.sub(r"\\\n\s*", " ", "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#")))
    return [line.strip() for line in text.splitlines() if line.strip()]


def install_steps(name: str) -> list[str]:
    """The instructions between FROM and the first ENV: what the image installs."""
    lines = instructions(name)
    assert lines[0].startswith("FROM "), lines[0]
    end = next(i for i, line in enumerate(lines) if line.startswith("ENV "))
    return lines[1:end]


def make_prerequisites(target: str) -> list[str]:
    makefile = (ROOT / "Makefile").read_text()
    m = re.search(rf"^{re.escape(target)}:([^\n]*)$", makefile, re.M)
    assert m, f"no target {target} in the Makefile"
    return m.group(1).split()


def test_both_images_install_the_same_way():
    assert install_steps(DOCKERFILES[0]) == install_steps(DOCKERFILES[1])


def test_the_images_run_make_serves_recipes():
    steps = install_steps("Dockerfile.cpu")
    runs = " ; ".join(s for s in steps if s.startswith("RUN "))
    # make serve = serve-deps (apt), the venv with the package, npm ci: the image runs the first and
    # the last through the Makefile itself and installs the package (not editable, no dev extras).
    assert make_prerequisites("serve") == ["serve-deps", "$(VENV)/.installed", "node_modules/.package-lock.json"]
    assert "make serve-deps" in runs and "make node_modules/.package-lock.json" in runs
    assert re.search(r"python3 -m venv /app/\.venv && .*/app/\.venv/bin/pip install .*/tmp/src", runs)
    copied = " ".join(s for s in steps if s.startswith("COPY "))
    for needed in ("Makefile", "package.json", "package-lock.json", "pyproject.toml"):
        assert needed in copied, f"the image does not copy {needed}"
    # every package pip installs is in the build context
    include = re.search(r"^include = \[(.*)\]$", (ROOT / "pyproject.toml").read_text(), re.M)
    assert include, "pyproject.toml lists no packages to include"
    for name in re.findall(r'"(\w+)\*"', include.group(1)):
        assert f"COPY {name} /tmp/src/{name}" in steps, f"package {name} is not copied into the image"


def test_the_page_finds_three_js_where_npm_ci_put_it():
    for name in DOCKERFILES:
        lines = instructions(name)
        workdir = next(line.split()[1] for line in lines if line.startswith("WORKDIR "))
        env = " ".join(line for line in lines if line.startswith("ENV "))
        assert f"DEPTHVIEW_NODE_MODULES={workdir}/node_modules" in env, name
        assert lines[-1].startswith("CMD ") and "depthview" in lines[-1] and "serve" in lines[-1], name


def test_the_build_context_leaves_out_what_the_images_do_not_need():
    ignored = [line.strip() for line in (ROOT / ".dockerignore").read_text().splitlines()
               if line.strip() and not line.startswith("#")]
    for heavy in (".venv", "node_modules", ".git", "data"):
        assert heavy in ignored, heavy
    for needed in ("Makefile", "package.json", "package-lock.json", "pyproject.toml", "README.md", "service"):
        assert needed not in ignored, needed
