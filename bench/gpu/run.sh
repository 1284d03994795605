#!/bin/bash
# Run on a lent GPU machine, in the repository root, with .whl and .gl carried (made by
# bench/gpu/prepare.sh): installs them, checks that GL runs on the GPU (not a software
# rasteriser), then runs each argument as a shell command, its output in $OUT/<n>.log.
# Benchmarks should write under /tmp/gpu (e.g. `python -m bench.reflections --out
# /tmp/gpu/reflections_gpu`); /tmp/gpu comes back as $OUT/gpu.tgz (bench/results holds
# what to keep: reflections_gpu.json, soft_shadows_gpu/).
# bench.soft_shadows writes into bench/results/soft_shadows: follow it with `cp bench/results/soft_shadows/*.json
# /tmp/gpu/`. Example:
#   bash bench/gpu/run.sh "python3 -m bench.reflections --scenes bathroom living_room --frames 0 \
#     --out /tmp/gpu/reflections_gpu"
export PYTHONUNBUFFERED=1
out=${OUT:-/tmp/gpu_out}
mkdir -p "$out" /tmp/gpu
for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
vendor=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f "$vendor" ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$vendor
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
  || exit 1
export PYTHONPATH=/tmp/site:$PWD GLCONTEXT_LINUX_LIBGL=libGL.so.1 GLCONTEXT_LINUX_LIBEGL=libEGL.so.1
python3 -c "
from gl_passes.context import create_gl_context
gl = create_gl_context()
print('GL', gl.renderer, '|', gl.version, '|', 'software' if gl.is_software else 'hardware')
" 2>&1 | tee "$out/00_gl.log"
grep -q "| hardware" "$out/00_gl.log" || { nvidia-smi 2>&1 | head -15; exit 2; }
n=0
for cmd in "$@"; do
  n=$((n + 1))
  echo "== $cmd"
  bash -c "$cmd" > "$out/$(printf %02d $n).log" 2>&1
  echo "rc=$? (log $(printf %02d $n).log)"
done
tar czf "$out/gpu.tgz" -C /tmp/gpu .
