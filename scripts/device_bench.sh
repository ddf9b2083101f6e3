#!/usr/bin/env bash
# CUDA check and GPU timings on a lent GPU machine, as one prepared script.
#
# The GPU machine has Python 3.12 with PyTorch, NumPy, SciPy, matplotlib, scikit-image, PyYAML,
# tqdm, threadpoolctl, hypothesis and pytest, but no network: Dr.Jit, Mitsuba (stripped to the CUDA
# polarised variant), Sionna RT, Dask and the pure-Python packages they import travel in an ignored
# folder (default .dev), made here by scripts/device_wheels.sh:
#   .dev/whl/*.whl             drjit, sionna-rt, trimesh, tomli_w, dask, distributed, ipywidgets,
#                              pythreejs, ... (cp312)
#   .dev/mitsuba_strip.tar.xz  the mitsuba 3.9.1 cp312 wheel's files with only the scalar_rgb and
#                              cuda_ad_mono_polarized variants and without render-only plugins
# Usage (from the repository root, on the GPU machine):  bash scripts/device_bench.sh OUTDIR
# SKIP="step ..." leaves steps out; TESTS="paths" replaces the test modules of the CUDA test step and
# PYTEST_LIMIT its time limit in seconds (default 150).
# Every step has its own time limit and the script goes on after a failed step, so one run gives
# everything that works; each step's output is in OUTDIR/<step>.log.
set -u
OUT=${1:?output folder}
DEV=${DEV:-.dev}
mkdir -p "$OUT"
SITE=/tmp/site
export DEV SITE
step() {  # step NAME SECONDS COMMAND...
  local name=$1 limit=$2; shift 2
  local t0=$(date +%s)
  case " ${SKIP:-} " in *" $name "*) echo "=== $name skipped"; return 0;; esac
  echo "=== $name (limit ${limit}s)"
  timeout "$limit" "$@" >"$OUT/$name.log" 2>&1
  local rc=$?
  echo "=== $name rc=$rc in $(( $(date +%s) - t0 )) s"
  tail -n 40 "$OUT/$name.log"
  return $rc
}

install() {
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$SITE" "$DEV"/whl/*.whl &&
  tar -xJf "$DEV/mitsuba_strip.tar.xz" -C "$SITE" &&
  PYTHONPATH="$SITE" python3 -m pip install -q --no-index --no-deps --no-build-isolation --no-compile \
      --target "$SITE" . &&
  mkdir -p "$SITE/bin" &&
  printf '#!/bin/sh\nexec python3 -c "import sys; from rfmitsuba.cli import main; sys.exit(main())" "$@"\n' \
      >"$SITE/bin/rfmitsuba" && chmod +x "$SITE/bin/rfmitsuba" &&
  { nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv || true; } &&
  python3 -c "import rfmitsuba, drjit as dr, mitsuba as mi; from rfmitsuba.core import backend as B; \
print('variant', B.set_variant(None), 'cuda', B.cuda_available(), 'drjit', dr.__version__, 'mitsuba', mi.__version__)"
}

export PYTHONPATH=$SITE PYTHONUNBUFFERED=1 PYTHONSAFEPATH=1 RFMITSUBA_VARIANT=${VARIANT:-cuda}
export PATH=$SITE/bin:$PATH
export -f install
step install 180 bash -c install || { echo "install failed"; exit 1; }
DS=$HOME/.cache/rfmitsuba/bench/nerf2like_200   # made by `bench field` (200 NeRF2-like tags)
step bench_field 170 rfmitsuba bench field --json "$OUT/bench_field.json"
step bench_splat 150 rfmitsuba bench splat --sizes 10000,50000 --json "$OUT/bench_splat.json"
# Training on CUDA as a user runs it: the splat field (EM network in half precision) and the
# default coherent field, each evaluated against the floors.
step train_splat 100 bash -c "rfmitsuba train $DS --model splat --out /tmp/r_splat --set iterations=600 --set seed=0 \
    && rfmitsuba eval /tmp/r_splat && cp /tmp/r_splat/eval/metrics.json $OUT/metrics_splat.json"
step train_coherent 150 bash -c "rfmitsuba train $DS --model coherent_gaussians --out /tmp/r_cg --set seed=0 \
    && rfmitsuba eval /tmp/r_cg && cp /tmp/r_cg/eval/metrics.json $OUT/metrics_coherent.json \
    && cp /tmp/r_cg/final/summary.json $OUT/summary_coherent.json"
# A dense folder (2000 NeRF2-like tags, generated on CUDA) with the default's 40 passes.
step train_dense 170 bash -c "rfmitsuba nerf2like --tags 2000 --out /tmp/n2k --quiet \
    && rfmitsuba train /tmp/n2k --model coherent_gaussians --out /tmp/r_n2k --set seed=0 && rfmitsuba eval /tmp/r_n2k \
    && cp /tmp/r_n2k/eval/metrics.json $OUT/metrics_dense.json && cp /tmp/r_n2k/final/summary.json $OUT/summary_dense.json"
# Stage 1 of the default field in a known room: bedroom, moving RX, 900 positions, empty room only.
step train_bedroom 170 bash -c "rfmitsuba generate bedroom --task rx --positions 900 --person-positions 0 \
    --out /tmp/bedroom_rx && rfmitsuba train /tmp/bedroom_rx --model coherent_gaussians --out /tmp/r_bed --set seed=0 \
    && rfmitsuba eval /tmp/r_bed && cp /tmp/r_bed/eval/metrics.json $OUT/metrics_bedroom.json \
    && cp /tmp/r_bed/log.jsonl $OUT/log_bedroom.jsonl"
# The test modules of the backend, the RF physics and the models, on CUDA. The LLVM alias test
# needs the LLVM variant, which the carried Mitsuba leaves out.
step pytest_cuda "${PYTEST_LIMIT:-150}" python3 -m pytest -q --no-header -p no:cacheprovider -o addopts="" \
    --deselect tests/core/test_backend.py::test_alias_and_unknown \
    ${TESTS:-tests/core/test_backend.py tests/rf tests/models/test_nn.py tests/models/coherent_gaussians \
    tests/models/test_splat.py}
gen() {  # Sionna RT on CUDA: 900 bedroom positions x 5 states (empty room + 4 person positions)
  local t0=$(date +%s.%N)
  rfmitsuba generate bedroom --task rx \
      --positions 900 --person-positions 4 --out /tmp/gen_bedroom || return
  python3 -c "import sys; n = 900 * 5; s = float(sys.argv[2]) - float(sys.argv[1]); print(f'{n} PAS in {s:.1f} s: {n / s:.1f} PAS/s')" "$t0" "$(date +%s.%N)"
}
export -f gen
step generate 80 bash -c gen
exit 0
