#!/usr/bin/env bash
# Create (or reuse) the project's virtual environment in .venv and install cosemdepth into it.
# torch is pinned to a CPU build (an open range would pull a multi-GB CUDA build).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [[ ! -x .venv/bin/python ]]; then
  "$PY" -m venv .venv
fi
if ! .venv/bin/python -c "import cosemdepth, torch, onnxruntime, pytest" 2>/dev/null \
   || [[ requirements-lock.txt -nt .venv/.installed ]] || [[ pyproject.toml -nt .venv/.installed ]]; then
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
  .venv/bin/python -m pip install -q -r requirements-lock.txt
  .venv/bin/python -m pip install -q --no-deps -e .
  touch .venv/.installed
fi
