#!/usr/bin/env bash
# One command: set up .venv (if needed), lint (ruff check, ruff format --check) and run the whole test suite
# (pytest-xdist: two worker processes).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ruff check --quiet .
.venv/bin/ruff format --check --quiet .
# two worker processes (one per core of the CI machine), each test file whole in one of them
exec .venv/bin/python -m pytest -q -n 2 --dist loadfile "$@"
