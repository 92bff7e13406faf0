#!/usr/bin/env bash
# Validate a GPU in one command (at most 8 minutes on one GPU): the device tests, streaming fp32/fp16/bf16 with and
# without CUDA graphs, batched throughput, training steps/s, DDP under torchrun (2 GPUs), ONNX Runtime's CUDA and
# TensorRT providers and a TensorRT fp16 engine, each against the PyTorch outputs; one JSON report (--out).
#   scripts/gpu_check.sh [--out gpu_check.json] [--stages ...] [--budget 480]
#   scripts/gpu_check.sh --dry-run            # CPU, tiny size: every stage planned, what the CPU can do is run
# Python: $PYTHON, else .venv/bin/python, else python3. See docs/benchmarks.md ("GPU check").
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
py="${PYTHON:-}"
if [ -z "$py" ]; then
  if [ -x "$root/.venv/bin/python" ]; then py="$root/.venv/bin/python"; else py="python3"; fi
fi
export PYTHONPATH="$root/src${PYTHONPATH:+:$PYTHONPATH}"
cd "$root"
exec "$py" -m cosemdepth.cli.gpu_check "$@"
