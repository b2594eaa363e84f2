#!/usr/bin/env bash
# The GPU check of issue 25, for the device machine: build gsplat, run the gpu-marked tests, run the
# end-to-end benchmark on one scene with the GPU preset. Prepared here by bench/gpu_check_prepare.py,
# which packs what the device image lacks into .whl/1, .whl/2, ... (64 MiB a call; open3d alone is
# 100 MB, carried as a 41 MB xz tarball). One device call per part, in order, on one warm machine, each the same command:
#
#     run(command="bash bench/gpu_check.sh", carry=[".whl/N"], timeout_s=540)
#
# Each call stashes its part in .gpu_stash (ignored; kept while the machine stays warm), installs
# what is complete, and runs every step the installed packages allow and that has not passed yet:
#   1. gsplat's CUDA build (JIT, ~60 s on an H100) and tests/gaussians/test_rasterize_cuda.py
#   2. once open3d is whole: the other gpu tests (tests/reconstruction/test_device.py: stage I and IV
#      on CUDA against the CPU from one seed)
#   3. after the last part: bench/bench_end_to_end.py on the carried scene, GPU preset, export skipped
#      (its usd-core and coacd are not carried): per-stage seconds and peak memory, and the joints.
#      E2E_WORKERS (default 4) stages run at once; E2E_THREADS, when set, caps every library's
#      threads (--threads): four stages in one process, each library sized for all 16 cores, may be
#      why the CPU stages gained little there (docs/performance.md), e.g.
#      run(command="E2E_THREADS=4 bash bench/gpu_check.sh", carry=[".whl/2"]).
# Logs and results come back under $OUT. Without a GPU (a dry run) every step says why it is skipped.
set -u -o pipefail
OUT=${OUT:-/tmp/gpu_check_out}
STASH=.gpu_stash
SITE=$STASH/site
mkdir -p "$OUT" "$STASH" "$SITE"
log() { echo "[gpu_check $(date +%H:%M:%S)] $*" | tee -a "$OUT/gpu_check.log"; }
PY=${PYTHON:-python3}

# Stash the carried parts (pieces of split wheels and the scene included).
for part in .whl/[0-9]*; do
  [ -d "$part" ] || continue
  log "stashing $part ($(du -sh "$part" | cut -f1))"
  cp -rn "$part"/. "$STASH"/ 2>/dev/null || cp -r "$part"/. "$STASH"/
done
[ -f "$STASH/manifest.json" ] || { log "no part carried yet: carry .whl/1 (bench/gpu_check_prepare.py makes it)"; exit 2; }

# Join split wheels whose pieces are all here, then install every complete wheel not yet installed.
"$PY" - "$STASH" <<'EOF'
import json, sys
from pathlib import Path
stash = Path(sys.argv[1])
files = json.loads((stash / "manifest.json").read_text())["files"]
for name, pieces in files.items():
    if len(pieces) > 1 and not (stash / name).exists() and all((stash / p).exists() for p in pieces):
        with open(stash / (name + ".tmp"), "wb") as out:
            for p in pieces:
                out.write((stash / p).read_bytes())
        (stash / (name + ".tmp")).rename(stash / name)
        for p in pieces:
            (stash / p).unlink()
missing = [n for n, p in files.items() if not (stash / n).exists()]
print("still to carry:", missing if missing else "nothing")
EOF
todo=()
for whl in "$STASH"/*.whl; do
  [ -f "$whl" ] && [ ! -f "$whl.installed" ] && todo+=("$whl")
done
install() { "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" "$@" >>"$OUT/pip.log" 2>&1; }
if [ ${#todo[@]} -gt 0 ]; then
  if install "${todo[@]}"; then  # one pip call for all; one at a time only if that fails
    for whl in "${todo[@]}"; do touch "$whl.installed"; done; log "installed ${#todo[@]} wheels"
  else
    for whl in "${todo[@]}"; do
      if install "$whl"; then touch "$whl.installed"; log "installed $(basename "$whl")"
      else log "FAILED to install $(basename "$whl") (see pip.log)"; fi
    done
  fi
fi
# System libraries open3d links (libGL, libX11, libudev, ...): only those the image lacks go on
# LD_LIBRARY_PATH, so none of the image's own is shadowed.
if [ -f "$STASH/syslibs.tar.xz" ]; then
  mkdir -p "$STASH/syslib/all" "$STASH/syslib/use"
  if [ ! -f "$STASH/syslibs.tar.xz.installed" ] && tar -xJf "$STASH/syslibs.tar.xz" -C "$STASH/syslib/all"; then
    for lib in "$STASH"/syslib/all/*; do
      name=$(basename "$lib")
      ldconfig -p | awk '{print $1}' | grep -qxF "$name" || ln -sf "$PWD/$lib" "$STASH/syslib/use/$name"
    done
    touch "$STASH/syslibs.tar.xz.installed"; log "system libraries the image lacks: $(ls "$STASH/syslib/use" | tr '\n' ' ')"
  fi
  export LD_LIBRARY_PATH="$PWD/$STASH/syslib/use${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
fi
# Tarballs (open3d, slimmed by gpu_check_prepare.slim_open3d) unpack straight into the site folder.
for tarball in "$STASH"/*.tar.xz; do
  [ "$(basename "$tarball")" != syslibs.tar.xz ] && [ -f "$tarball" ] && [ ! -f "$tarball.installed" ] || continue
  if tar -xJf "$tarball" -C "$SITE"; then touch "$tarball.installed"; log "unpacked $(basename "$tarball")"
  else log "FAILED to unpack $(basename "$tarball")"; fi
done
# open3d.visualization imports its plotly drawing (plotly, dash), which the image lacks and the
# pipeline never calls: a stand-in module whose every name raises when called.
if [ -f "$SITE/open3d/visualization/draw_plotly.py" ] && ! "$PY" -c "import plotly, dash" >/dev/null 2>&1 \
   && ! grep -q _missing "$SITE/open3d/visualization/draw_plotly.py"; then
  printf 'def _missing(*a, **k):\n    raise ImportError("plotly and dash are not installed here")\n\n\ndef __getattr__(name):\n    if name.startswith("__"):\n        raise AttributeError(name)\n    return _missing\n' \
    > "$SITE/open3d/visualization/draw_plotly.py"
  log "open3d's plotly drawing stubbed (plotly and dash are not in the image)"
fi
# The export stage is skipped (usd-core and coacd are not carried), but importing the stages imports
# its module, which imports pxr: an empty stand-in lets that import succeed (never called).
if ! "$PY" -c "import pxr" >/dev/null 2>&1 && [ ! -d "$SITE/pxr" ]; then
  mkdir -p "$SITE/pxr"; for m in __init__ Gf Sdf Usd UsdGeom UsdPhysics UsdVol Vt; do : > "$SITE/pxr/$m.py"; done
  log "pxr stand-in installed (the export stage does not run here)"
fi
export PYTHONPATH="$SITE:$PWD${PYTHONPATH:+:$PYTHONPATH}"
export PYTHONUNBUFFERED=1 ARTITWIN_HOME="$STASH/home"

has() { "$PY" -c "import $1" >/dev/null 2>&1; }
gpu=0
"$PY" -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)" && gpu=1
log "python $("$PY" -c 'import sys, torch; print(sys.version.split()[0], "torch", torch.__version__, "cuda", torch.cuda.is_available())')"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null | tee -a "$OUT/gpu_check.log"

# 1. gsplat: its first import of the CUDA kernels builds them (JIT); time it.
if [ "$gpu" = 1 ] && has gsplat && [ ! -f "$STASH/gsplat.built" ]; then
  log "building gsplat's CUDA kernels (JIT)"
  start=$(date +%s)
  if "$PY" - >>"$OUT/gsplat_build.log" 2>&1 <<'EOF'
import torch
from gsplat import rasterization
n = 1000
dev = "cuda"
means = torch.randn(n, 3, device=dev) + torch.tensor([0, 0, 3.0], device=dev)
quats = torch.randn(n, 4, device=dev)
scales = torch.rand(n, 3, device=dev) * 0.05
opac = torch.rand(n, device=dev)
colors = torch.rand(n, 16, 3, device=dev)
K = torch.tensor([[100.0, 0, 64], [0, 100.0, 48], [0, 0, 1]], device=dev)[None]
img, alpha, meta = rasterization(means, quats, scales, opac, colors, torch.eye(4, device=dev)[None], K, 128, 96, sh_degree=3)
torch.cuda.synchronize()
print("gsplat ok", img.shape)
EOF
  then touch "$STASH/gsplat.built"; log "gsplat built in $(( $(date +%s) - start )) s"
  else log "gsplat build FAILED (see gsplat_build.log)"; fi
elif [ "$gpu" = 0 ]; then log "no CUDA device: gsplat build and the gpu tests are skipped (dry run)"
elif ! has gsplat; then log "gsplat not installed yet (carry .whl/1)"; fi

# 2. The gpu-marked tests that the installed packages allow, each file once it has passed.
run_tests() {  # $1: tag, rest: test files
  local tag=$1; shift
  [ -f "$STASH/tests_$tag.passed" ] && { log "gpu tests $tag passed in an earlier call"; return; }
  log "gpu tests $tag: $*"
  # No pytest-xdist there: pyproject's addopts (-n 2) would be an unknown option.
  if "$PY" -m pytest -q -m gpu -p no:cacheprovider -o addopts="-ra --strict-markers" "$@" 2>&1 | tee "$OUT/tests_$tag.log" | tail -3; then
    grep -q " passed" "$OUT/tests_$tag.log" && ! grep -qE " (failed|error)" "$OUT/tests_$tag.log" && touch "$STASH/tests_$tag.passed"
  fi
}
if [ "$gpu" = 1 ] && [ -f "$STASH/gsplat.built" ]; then
  has lzfse && has OpenEXR && run_tests rasterizer tests/gaussians/test_rasterize_cuda.py
  if has open3d && has pydantic; then run_tests training tests/reconstruction/test_device.py
  else log "open3d or pydantic not installed yet: the training gpu tests wait for the next part"; fi
fi

# 3. The end-to-end benchmark on the carried scene, once everything it imports is installed.
if [ -d "$STASH/scene" ] && has open3d && has pycolmap && has pydantic && has zarr && has lzfse; then
  if [ "$gpu" = 1 ] && [ -f "$STASH/gsplat.built" ]; then
    log "end-to-end benchmark on $STASH/scene (GPU preset)"
    "$PY" bench/bench_end_to_end.py --scenes a-door --scene-dir "$STASH/scene" --skip-stages export \
      --workers "${E2E_WORKERS:-4}" ${E2E_THREADS:+--threads "$E2E_THREADS"} --workdir "$STASH/e2e" --name end_to_end_gpu \
      2>&1 | tee "$OUT/end_to_end.log" | tail -40
    cp bench/results/end_to_end_gpu.json "$OUT/" 2>/dev/null
  else
    log "end-to-end benchmark skipped: no CUDA device or gsplat not built (dry run)"
  fi
else
  log "end-to-end benchmark waits for the scene, open3d, pycolmap, pydantic, zarr and lzfse"
fi
log "done"
