#!/usr/bin/env bash
# Reproduce the shipped demo weights (weights/synthair-cosemdepth/) with the project's own commands:
# 1. SynthAir training data in data/: six worlds (seeds 11-16; three trajectories per climate, all of them used for
#    training through `cosemdepth splits --rule train`) and a seventh (seed 17, one trajectory per climate) for
#    validation; the demo evaluates on yet another world (seed 1001). 128x128, 3x supersampled colour, sunny and
#    cloudy climates.
# 2. Stage 1: cosemdepth train with src/cosemdepth/configs/synthair-demo.yaml (Co-SemDepth, 5 levels, 7 classes, bf16
#    autocast, 18 epochs, 5,184 steps) into runs/synthair-demo.
# 3. Stage 2: six epochs of fine-tuning of stage 1's best model (train.init_weights) with the semantic loss weighted
#    per class (the square root of median-frequency balancing over the six training worlds, printed by
#    `python scripts/class_weights.py --config synthair-demo`; stage 1 never predicts the two smallest classes,
#    boulders and others), lr 6e-5 then 1.8e-5 from epoch 4, validation every epoch, into runs/synthair-demo-finetune.
# 4. Stage 2's best checkpoint (design 9.5 rule on the validation world) is written to weights/synthair-cosemdepth in
#    float16, with its training curve (weights/synthair-cosemdepth/training_curve.csv and .png; stage 1's curve is
#    kept beside it as stage1_training_curve.csv and .png).
# The shipped stage 2 started from the float16 copy of stage 1's best model (the weights shipped before it); this
# script starts it from runs/synthair-demo/best in float32, a difference of float16 rounding.
# CPU-only, on a 2-core machine: stage 1 on 2026-12-02 on an Intel Xeon with AVX512-BF16 and AMX (shared with another
# 1-thread job most of the time): 36 minutes of data generation (2 render processes, about 0.5 s per frame of 384x384
# rays each) and 1 h 42 min of training; the same 18 epochs take about 2 h 20 min on the 2-core AMD EPYC without AMX
# (0.46-0.74 steps/s). Stage 2 on the 2-core AMD EPYC (2026-12-02): 44 min for its 1,728 steps.
# With the trainer of 2026-12-03 (frame 0's semantic decoder skipped, faster colour augmentation) one epoch of stage 1
# took 4 min 35 s of training (1.05 steps/s) and 6 s of validation on the 2-core AMD EPYC (03:26 UTC; `cosemdepth train
# --config synthair-demo --epochs 1 --set train.validate_every_epochs=1`): both stages' 24 epochs, about 1 h 53 min
# (the host's speed varies: at 0.82 steps/s, seen in its slow hours, about 2 h 23 min).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# The renders run several processes at once: their OpenMP threads sleep rather than spin while waiting. Training does
# not: with sleeping threads our trainer made 0.74-0.80 steps/s instead of 0.88-0.89 (0.86x; 2026-12-03, 2-core AMD EPYC,
# 128 px, batch 3, seq 4, bf16, docs/log.md); this script used to set it for all.
CLI=.venv/bin/cosemdepth
RUN=${RUN:-runs/synthair-demo}
# The recipe trains with bf16 autocast; a CPU without bf16 convolutions (AVX2 only) trains in float32 instead (fp32
# and bf16 runs learn alike, docs/benchmarks.md; on a 2-core AVX2-only AMD EPYC fp32 ran at about 0.3 steps/s: hours).
PRECISION=()
if ! .venv/bin/python -c "import sys; from cosemdepth.devices import bf16_convolutions; sys.exit(not bf16_convolutions())"; then
  echo "make_demo_weights: this CPU has no bf16 convolutions: training in float32 (train.bf16=false)" >&2
  PRECISION=(--set train.bf16=false)
fi
for seed in 11 12 13 14 15 16 17; do
  traj=3; [ "$seed" = 17 ] && traj=1
  OMP_WAIT_POLICY=PASSIVE $CLI synth --out "data/synthair-demo-s$seed" --trajectories "$traj" --frames 400 --size 128 --seed "$seed" \
    --climates sunny cloudy --supersample 3 --workers 2 --no-progress
  [ "$seed" = 17 ] || $CLI splits synthair "data/synthair-demo-s$seed" "data/splits-all/synthair-demo-s$seed" --rule train
done
$CLI train --config synthair-demo --out "$RUN" "${PRECISION[@]}"
$CLI train --config synthair-demo --out "$RUN-finetune" "${PRECISION[@]}" --init-weights "$RUN/best" --epochs 6 --lr 6e-5 --seed 7 \
  --set "train.lr_decay_epochs=[4]" --set train.validate_every_epochs=1 \
  --set "train.semantic_class_weights=[0.727, 1.0, 0.681, 0.592, 1.991, 1.252, 2.275]"
.venv/bin/python scripts/ship_weights.py "$RUN-finetune" weights/synthair-cosemdepth
.venv/bin/python scripts/ship_weights.py "$RUN" "$RUN-weights"  # stage 1 alone, for its training curve
for ext in csv png; do cp "$RUN-weights/training_curve.$ext" "weights/synthair-cosemdepth/stage1_training_curve.$ext"; done
