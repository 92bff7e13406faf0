#!/usr/bin/env bash
# One command: set up .venv (if needed) and run the demo; the report goes to demo_report/ (or $1).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/cosemdepth demo --out "${1:-demo_report}"
