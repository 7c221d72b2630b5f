#!/usr/bin/env bash
# The main job: set up, then a 10-minute D4PG training run on Hopper (5M env steps at most), on the
# GPU with the gpu preset where nvidia-smi finds one, else on the CPU; then a video of the best
# policy. Arguments go to `mjx-hopper train`; for example --max-minutes 30.
set -euo pipefail
cd "$(dirname "$0")/.."
preset=cpu
cuda=$(nvidia-smi 2>/dev/null | sed -n 's/.*CUDA Version: *\([0-9]*\)\..*/\1/p' || true)
if [ -n "$cuda" ]; then
  extra=cuda; [ "$cuda" -lt 13 ] && extra=cuda12
  echo "NVIDIA GPU found (its driver runs CUDA $cuda): installing JAX's CUDA build ([$extra]) and" \
       "training the gpu preset"
  bash scripts/setup.sh "$extra"
  preset=gpu
else
  echo "no NVIDIA GPU found: training the cpu preset on the CPU"
  bash scripts/setup.sh
fi
.venv/bin/mjx-hopper train --env Hopper --agent d4pg --preset "$preset" \
  --total-env-steps 5000000 --max-minutes 10 --out-dir runs/main "$@"
.venv/bin/mjx-hopper eval --checkpoint runs/main/checkpoints --video runs/main/policy.mp4
