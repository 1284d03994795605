# depthview: `make serve` and `make test` each do the whole idempotent setup first.
VENV ?= .venv
PY := $(VENV)/bin/python
APT_PKGS := libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 g++ python3-dev
HOST ?= 0.0.0.0
PORT ?= 8000

.PHONY: system-deps setup serve test test-all lint bench
system-deps:
	@missing=""; for p in $(APT_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	python3 -c 'import ensurepip, venv' >/dev/null 2>&1 || missing="$$missing python3-venv python3-pip"; \
	if [ -n "$$missing" ]; then \
	  echo "installing system packages:$$missing"; \
	  SUDO=$$( [ "$$(id -u)" -eq 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$missing; \
	fi

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $@

setup: system-deps $(VENV)/.installed

serve: setup
	$(VENV)/bin/depthview serve --host $(HOST) --port $(PORT)

test: setup
	$(PY) -m pytest -q

test-all: setup
	$(PY) -m pytest -q -m ''

lint: setup
	$(VENV)/bin/ruff check .

bench: setup
	$(PY) -m bench.render_throughput
