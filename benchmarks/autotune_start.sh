#!/usr/bin/env bash
# The start with XLA's GPU autotuning results shipped: one run of the gpu preset (a fresh
# compile cache) dumps them, then start_time.py times fresh processes with them loaded and
# without, each from an empty compile cache and then from the cache it left:
#   bash benchmarks/gpu.sh "bash benchmarks/autotune_start.sh"
# AUTOTUNE_FILE names the dump (default: $OUT/autotune.textproto, which comes back).
set -uo pipefail
at=${AUTOTUNE_FILE:-${OUT:-/tmp}/autotune.textproto}
cache=$(mktemp -d)
out=$(mktemp -d)
MJX_HOPPER_JAX_CACHE=$cache XLA_FLAGS="--xla_gpu_dump_autotune_results_to=$at" \
  python -P -m mjx_hopper.cli train --env Hopper --agent d4pg --preset gpu --steps 1000000000 \
  --no-progress --log-every 1 --max-minutes 0.5 --out "$out" >"$out/log.txt" 2>&1
grep -m 1 '^\[train\]' "$out/log.txt" || tail -20 "$out/log.txt"
ls -la "$at"
XLA_FLAGS="--xla_gpu_load_autotune_results_from=$at" python benchmarks/start_time.py \
  --kind gpu --rounds 1 --seconds 40 --label h100_autotune_loaded
python benchmarks/start_time.py --kind gpu --rounds 1 --seconds 40 --label h100_autotune_none
