#!/usr/bin/env bash
# Build the ignored folder that scripts/device_bench.sh installs from on a lent GPU machine.
#
# The GPU machine runs Python 3.12 with PyTorch, NumPy, SciPy, matplotlib, scikit-image, PyYAML,
# tqdm, hypothesis and pytest already there, and reaches no package index. This script (run here,
# where PyPI is reachable) downloads the cp312 manylinux wheels of what the project needs beyond
# that, and packs Mitsuba 3.9.1 without the variants the GPU run never loads, so that the whole
# working tree stays under the device tool's 64 MiB:
#   DEV/whl/*.whl             drjit, sionna-rt, trimesh, tomli_w, dask, distributed and the
#                             pure-Python packages they import that the machine lacks
#   DEV/mitsuba_strip.tar.xz  mitsuba/ with only the scalar_rgb and cuda_ad_mono_polarized variants
#                             and without render-only plugins
# Usage: bash scripts/device_wheels.sh [DEV]   (default .dev; add it to .git/info/exclude)
set -euo pipefail
DEV=${1:-.dev}
PY=$(command -v "${PYTHON:-python3}")
case $PY in /*) ;; *) PY=$PWD/$PY;; esac
DL=$(mktemp -d)
trap 'rm -rf "$DL"' EXIT
PLAT="--only-binary=:all: --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64
      --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64
      --platform manylinux1_x86_64 --platform any"
# shellcheck disable=SC2086
"$PY" -m pip download -q $PLAT -d "$DL" "sionna-rt==2.2.0" "drjit==1.5.0" "mitsuba==3.9.1" \
    "trimesh==5.2.0" "tomli_w==1.2.0" "dask==2026.8.0" "distributed==2026.8.0"
# Already on the GPU machine's image (KINDS.md's package list): not carried.
PRESENT="numpy scipy matplotlib scikit_image pillow contourpy fonttools kiwisolver cycler pyparsing
 python_dateutil packaging networkx imageio tifffile lazy_loader pyyaml tqdm threadpoolctl hypothesis
 sortedcontainers msgpack psutil cloudpickle toolz fsspec click jinja2 markupsafe pygments
 typing_extensions tzdata zipp six
 widgetsnbextension jupyterlab_widgets"  # the last two: notebook front-end assets, never imported
rm -rf "$DEV/whl" && mkdir -p "$DEV/whl"
for whl in "$DL"/*.whl; do
  name=$(basename "$whl" | cut -d- -f1 | tr 'A-Z' 'a-z')
  case " $(echo $PRESENT) mitsuba " in *" $name "*) continue;; esac
  cp "$whl" "$DEV/whl/"
done
STRIP=$(mktemp -d)
(cd "$STRIP" && "$PY" -m zipfile -e "$DL"/mitsuba-3.9.1-*.whl . >/dev/null)
find "$STRIP/mitsuba" -maxdepth 1 -name '*_*.cpython-312-x86_64-linux-gnu.so' \
    ! -name 'scalar_rgb.*' ! -name 'cuda_ad_mono_polarized.*' ! -name 'mitsuba_*' -delete
# Render-only plugins (volumes, curves, sky models, rough BSDFs, light tracing) that neither the
# scenes (ply shapes, Sionna's radio materials) nor Sionna's own scene set-up instantiate.
for plugin in ellipsoids ellipsoidsmesh volpath volpathmis bsplinecurve linearcurve sdfgrid sunsky \
    timed_sunsky ptracer principled principledthin hair measured measured_polarized roughplastic \
    pplastic roughdielectric roughconductor thinlens projector spot gridvolume; do
  rm -f "$STRIP/mitsuba/plugins/$plugin.so"
done
tar -cJf "$DEV/mitsuba_strip.tar.xz" -C "$STRIP" .
rm -rf "$STRIP"
du -sh "$DEV"/whl "$DEV"/mitsuba_strip.tar.xz
