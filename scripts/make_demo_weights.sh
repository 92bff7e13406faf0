#!/usr/bin/env bash
# Reproduce the shipped demo weights (weights/synthair-cosemdepth/) with the project's own commands:
# 1. SynthAir training data in data/: six worlds (seeds 11-16; three trajectories per climate, all of them used for
#    training through `cosemdepth splits --rule train`) and a seventh (seed 17, one trajectory per climate) for
#    validation; the demo evaluates on yet another world (seed 1001). 128x128, 3x supersampled colour, sunny and
#    cloudy climates.
# 2. cosemdepth train with src/cosemdepth/configs/synthair-demo.yaml (Co-SemDepth, 5 levels, 7 classes, bf16 autocast).
# 3. The best checkpoint (spec 8.5 rule on the validation world) is written to weights/synthair-cosemdepth in
#    float16, with its training curve (weights/synthair-cosemdepth/training_curve.csv and .png).
# CPU-only, on a 2-core machine (2026-12-02, Intel Xeon with AVX512-BF16, shared with another 1-thread job most of
# the time): 36 minutes of data generation (2 render processes, about 0.5 s per frame of 384x384 rays each) and 1 h
# 42 min of training (5,184 steps; about 1 h 20 min estimated alone, at 1.14 steps/s with 2 threads).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export OMP_WAIT_POLICY=PASSIVE
CLI=.venv/bin/cosemdepth
RUN=${RUN:-runs/synthair-demo}
for seed in 11 12 13 14 15 16 17; do
  traj=3; [ "$seed" = 17 ] && traj=1
  $CLI synth --out "data/synthair-demo-s$seed" --trajectories "$traj" --frames 400 --size 128 --seed "$seed" \
    --climates sunny cloudy --supersample 3 --workers 2 --no-progress
  [ "$seed" = 17 ] || $CLI splits synthair "data/synthair-demo-s$seed" "data/splits-all/synthair-demo-s$seed" --rule train
done
$CLI train --config synthair-demo --out "$RUN"
.venv/bin/python scripts/ship_weights.py "$RUN" weights/synthair-cosemdepth
