#!/bin/bash
# Run here, in the repository root, before using a lent GPU machine (../.library/device):
# it has Python 3.12, numpy and NVIDIA's driver but none of moderngl, glcontext, embreex,
# meshoptimizer nor the GL dispatch libraries, and reaches no registry. This puts cp312
# wheels of the versions in .venv into .whl/ (meshoptimizer has no wheel: built here with
# a Python 3.12) and Debian's libglvnd/EGL packages into .gl/ (both git-ignored); carry
# both (and nothing else) to the device and start its command with bench/gpu/run.sh.
set -euo pipefail
PY=${PY:-.venv/bin/python}
if [ -z "${PY312:-}" ]; then  # python3.12 on PATH, else a pyenv install
  for c in python3.12 "$HOME"/.pyenv/versions/3.12*/bin/python; do
    if "$c" -c pass 2>/dev/null; then PY312=$c; break; fi
  done
fi
: "${PY312:?no Python 3.12 found: set PY312}"
version() { "$PY" -c "from importlib.metadata import version; print(version('$1'))"; }
mkdir -p .whl .gl
platforms=()
for tag in manylinux_2_17 manylinux2014 manylinux1 manylinux_2_24 manylinux_2_27 manylinux_2_28 manylinux_2_31 \
           manylinux_2_34 manylinux_2_35; do platforms+=(--platform "${tag}_x86_64"); done
for pkg in moderngl glcontext embreex; do
  "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    "${platforms[@]}" -d .whl "$pkg==$(version "$pkg")"
done
"$PY312" -m pip wheel -q --no-deps -w .whl "meshoptimizer==$(version meshoptimizer)"
lists=$(mktemp -d)
mkdir -p "$lists/partial"
apt_opts=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 "-oDir::State::Lists=$lists")
apt-get "${apt_opts[@]}" update -qq
(cd .gl && apt-get "${apt_opts[@]}" download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
ls -l .whl .gl
