"""Issue 15, item 7: the Docker images install what `make serve` installs. The images are
built by `make docker-test` (not in the default suite); these checks read the files, so
the two images cannot drift apart nor away from the Makefile's recipes, nor lose what the
Docker review fixed (non-root user, environment over options, healthcheck, slim layers)."""

from __future__ import annotations

import re

from tests.helpers import ROOT

DOCKERFILES = ("Dockerfile.cpu", "Dockerfile.nvidia")


def instructions(name: str) -> list[str]:
    """The Dockerfile's instructions, continuation lines joined, comments dropped."""
    text = (ROOT / "docker" / name).read_text()
    text = re.sub(r"\\\n\s*", " ", "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#")))
    return [line.strip() for line in text.splitlines() if line.strip()]


def after_from(name: str) -> list[str]:
    """The instructions after FROM (before it: only ARG BASE, the base image FROM names)."""
    lines = instructions(name)
    start = next(i for i, line in enumerate(lines) if line.startswith("FROM "))
    assert lines[start] == "FROM ${BASE}" and lines[:start] == [next(a for a in lines if a.startswith("ARG BASE="))]
    return lines[start + 1:]


def install_steps(name: str) -> list[str]:
    """The instructions between FROM and the first ENV: what the image installs."""
    lines = after_from(name)
    end = next(i for i, line in enumerate(lines) if line.startswith("ENV "))
    return lines[:end]


def env(name: str) -> dict[str, str]:
    """The image's ENV variables (ENV k=v ... lines)."""
    pairs = " ".join(line[4:] for line in instructions(name) if line.startswith("ENV ")).split()
    assert all("=" in p for p in pairs), pairs
    return dict(p.split("=", 1) for p in pairs)


def make_prerequisites(target: str) -> list[str]:
    makefile = (ROOT / "Makefile").read_text()
    m = re.search(rf"^{re.escape(target)}:([^\n]*)$", makefile, re.M)
    assert m, f"no target {target} in the Makefile"
    return m.group(1).split()


def test_both_images_install_the_same_way():
    assert install_steps(DOCKERFILES[0]) == install_steps(DOCKERFILES[1])
    # ... and run the same way: only the base image and the NVIDIA_* variables differ
    rest = [[line for line in after_from(n) if not line.startswith("ENV ")] for n in DOCKERFILES]
    assert rest[0] == rest[1]
    cpu, gpu = env(DOCKERFILES[0]), env(DOCKERFILES[1])
    assert cpu == {k: v for k, v in gpu.items() if not k.startswith("NVIDIA_")}
    assert instructions(DOCKERFILES[0])[0] == "ARG BASE=debian:bookworm-slim"  # test.sh passes a stand-in


def test_the_images_run_as_a_user_who_owns_data():
    for name in DOCKERFILES:
        lines = after_from(name)
        users = [line.split()[1] for line in lines if line.startswith("USER ")]
        assert users and users[-1].split(":")[0] not in ("0", "root"), name
        uid = users[-1].split(":")[0]
        useradd = next(line for line in lines if "useradd" in line)
        assert f"--uid {uid}" in useradd and re.search(r"chown \S+ /data\b", useradd), useradd
        # /data is the user's before VOLUME, so a new named volume starts out the user's
        assert lines.index(useradd) < lines.index("VOLUME /data"), name
        assert env(name)["DEPTHVIEW_DATA_DIR"] == "/data"


def test_the_environment_configures_the_service():
    for name in DOCKERFILES:
        variables = env(name)
        cmd = instructions(name)[-1]
        # CMD passes no options: they would win over DEPTHVIEW_HOST / DEPTHVIEW_PORT (docker run -e)
        assert cmd == 'CMD ["/app/.venv/bin/depthview", "serve"]', cmd
        assert variables["DEPTHVIEW_HOST"] == "0.0.0.0"
        assert f"EXPOSE {variables['DEPTHVIEW_PORT']}" in instructions(name)
        # no GL backend (it would turn off the OSMesa fallback) nor device (it pinned every worker to GPU 0)
        assert not any(k.startswith("DEPTHVIEW_GL") for k in variables), name
        assert variables["PATH"].startswith("/app/.venv/bin:")  # docker run IMAGE depthview scenes


def test_the_healthcheck_asks_readyz_with_the_images_python():
    for name in DOCKERFILES:
        check = next(line for line in instructions(name) if line.startswith("HEALTHCHECK "))
        assert re.search(r"--interval=\d+s --timeout=\d+s --start-period=\d+s", check), check
        assert 'CMD ["/app/.venv/bin/python", "-c"' in check
        assert "http://127.0.0.1:" in check and "DEPTHVIEW_PORT" in check and "/readyz" in check


def test_the_images_keep_no_apt_lists_nor_build_certificates():
    for name in DOCKERFILES:
        runs = [line for line in after_from(name) if line.startswith("RUN ")]
        apt = next(line for line in runs if "make serve-deps" in line)
        assert "make serve-deps APT_FLAGS=--no-install-recommends" in apt
        assert "apt-get clean" in apt and "rm -rf /var/lib/apt/lists/* /var/cache/apt/*" in apt
        # extra CA certificates come as a BuildKit secret: a build argument's value stays in the history
        assert not any(line.startswith("ARG ") for line in after_from(name)), name
        fetching = [line for line in runs if "/tmp/ca.pem" in line]
        assert len(fetching) == 2 and all(line.startswith("RUN --mount=type=secret,id=ca ") for line in fetching)
    assert re.search(r"^APT_FLAGS \?=$", (ROOT / "Makefile").read_text(), re.M)  # host installs: apt's default


def test_docker_test_leaves_no_volume_and_shadows_no_base_image():
    script = (ROOT / "docker" / "test.sh").read_text()
    assert "docker rm -f -v" in script
    assert "--build-arg BASE=" in script and "--secret id=ca," in script
    assert "BUILD_CA_PEM" not in script


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
