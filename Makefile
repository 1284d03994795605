# depthview: `make serve` and `make test` each do the whole idempotent setup first (apt packages,
# the .venv, npm ci). The Docker images (docker/) run the same serve-deps recipe and npm ci.
VENV ?= .venv
PY := $(VENV)/bin/python
# What serving needs: Mesa EGL/OSMesa (libgl1: moderngl's EGL backend loads libGL.so.1), a compiler
# for meshoptimizer's sdist, Python's venv, Node/npm for three.js (npm ci), and CA certificates for
# pip and npm. libgl1 and ca-certificates come only as recommends of the others, so they are named
# here for installs without recommends.
APT_PKGS := libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libosmesa6 g++ python3-dev ca-certificates
# Extra apt-get install options: the Docker images pass --no-install-recommends (a host install
# keeps apt's default, recommends included).
APT_FLAGS ?=
# system-deps adds the browser test's Chromium (chromium-headless-shell where Debian has it, else
# chromium; driven by Playwright from PyPI, never `playwright install`)
HOST ?= 0.0.0.0
PORT ?= 8000
DOCKER_IMAGE ?= depthview:cpu

.PHONY: serve-deps system-deps setup serve test test-all lint bench docker-test
# $(1): 1 to add Chromium as well
define apt_install
	@missing=""; for p in $(APT_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	python3 -c 'import ensurepip, venv' >/dev/null 2>&1 || missing="$$missing python3-venv python3-pip"; \
	command -v npm >/dev/null 2>&1 || missing="$$missing nodejs npm"; \
	chromium=""; [ "$(1)" = 1 ] && { dpkg -s chromium-headless-shell >/dev/null 2>&1 || dpkg -s chromium >/dev/null 2>&1 || chromium=1; }; \
	if [ -n "$$missing$$chromium" ]; then \
	  SUDO=$$( [ "$$(id -u)" -eq 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq || exit 1; \
	  if [ -n "$$chromium" ]; then \
	    if apt-cache show chromium-headless-shell >/dev/null 2>&1; then missing="$$missing chromium-headless-shell"; \
	    else missing="$$missing chromium"; fi; \
	  fi; \
	  echo "installing system packages:$$missing"; \
	  DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $(APT_FLAGS) $$missing; \
	fi
endef

serve-deps:
	$(call apt_install,0)

system-deps:
	$(call apt_install,1)

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $@

# three.js for the /client page and Swagger UI for /docs (package.json + lock file; node_modules is git-ignored)
node_modules/.package-lock.json: package.json package-lock.json
	npm ci --ignore-scripts --no-audit --no-fund --loglevel=error

setup: system-deps $(VENV)/.installed node_modules/.package-lock.json

serve: serve-deps $(VENV)/.installed node_modules/.package-lock.json
	$(VENV)/bin/depthview serve --host $(HOST) --port $(PORT)

test: setup
	$(PY) -m pytest -q

test-all: setup
	$(PY) -m pytest -q -m ''

lint: setup
	$(VENV)/bin/ruff check .

bench: setup
	$(PY) -m bench.render_throughput

# Builds the CPU image (docker/Dockerfile.cpu) and runs the service smoke test in it (docker/test.sh:
# starts dockerd if needed, imports a debootstrapped Debian root when the base image cannot be
# pulled). Not part of `make test`.
docker-test:
	DOCKER_IMAGE=$(DOCKER_IMAGE) bash docker/test.sh
