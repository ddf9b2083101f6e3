#!/usr/bin/env bash
# Set up rfmitsuba on a fresh machine, idempotently:
#   1. a libLLVM >= 16 for Dr.Jit's LLVM backend (Debian's libllvm19 where none is present);
#   2. a virtual environment in .venv with rfmitsuba and its test extras installed.
# Called by `make setup` (and so by `make demo` and `make test`).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=${VENV:-.venv}

if ! "$PY" -c 'import sys; sys.path.insert(0, "rfmitsuba/core"); import _llvm; sys.exit(0 if _llvm.find_libllvm() else 1)'; then
  echo "setup: no libLLVM >= 16 found; installing Debian's libllvm19" >&2
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
  elif command -v sudo >/dev/null && command -v apt-get >/dev/null; then
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
  else
    echo "setup: cannot install libLLVM here. Install libLLVM >= 16 (Debian/Ubuntu: apt-get install libllvm19)" >&2
    echo "       or set DRJIT_LIBLLVM_PATH to a libLLVM.so of version 16 or newer." >&2
    exit 1
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
"$VENV/bin/python" -m pip install -q -e ".[test]"
"$VENV/bin/python" -m ipykernel install --sys-prefix --name python3 >/dev/null 2>&1 || true
touch "$VENV/.installed"
"$VENV/bin/rfmitsuba" info
