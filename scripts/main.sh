#!/usr/bin/env bash
# The main job: set up, then D4PG on Hopper with its preset and the preset's budget (env steps and
# minutes, whichever ends first: what its benchmark needed to reach the Hopper's score), the gpu
# preset with JAX's CUDA build where nvidia-smi finds a GPU, else the cpu one; then a video of the
# best policy. Arguments go to `mjx-hopper train`; for example --max-minutes 30.
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
.venv/bin/mjx-hopper train --env Hopper --agent d4pg --preset "$preset" --out-dir runs/main "$@"
.venv/bin/mjx-hopper eval --checkpoint runs/main/checkpoints --video runs/main/policy.mp4
