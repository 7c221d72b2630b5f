#!/usr/bin/env bash
# The gpu preset's training chunk (Hopper, D4PG, one member on one GPU, 512 envs, batch 1,024):
# its compile time with XLA's default flags and with --xla_gpu_force_compilation_parallelism=16,
# two rounds, each run a fresh process with an empty compile cache; then one more run with XLA's
# phase timers logged (RunHloPasses, RunBackend, IR emission). On the GPU:
#   bash benchmarks/gpu.sh "bash benchmarks/compile_flags.sh"
# (XLA of jax 0.11.2 refuses --xla_gpu_enable_llvm_module_compilation_parallelism: unknown.)
set -uo pipefail
OUT=${OUT:-runs/compile_flags}
mkdir -p "$OUT"
chunk() {  # NAME: one run; its output in $OUT/NAME.txt, its row in $OUT/NAME.json
  local cache
  cache=$(mktemp -d)
  MJX_HOPPER_JAX_CACHE=$cache python benchmarks/sweep_throughput.py --preset gpu --num-envs 512 \
    --batch-size 1024 --replay-size 100000 --chunk 10 --chunks 1 --members 1 --gpus 1 \
    --out "$OUT/$1.json" >"$OUT/$1.txt" 2>&1
  rm -rf "$cache"
}
compile_s() {  # NAME: that run's compile seconds, or where its output is
  python -c "import json, sys; print(round(json.load(open(sys.argv[1]))['rows'][0]['compile_s'], 1))" \
    "$OUT/$1.json" 2>/dev/null || echo "failed: $OUT/$1.txt"
}
echo "| round | XLA_FLAGS | chunk's compile (s) |"
echo "|---|---|---|"
for round in 1 2; do
  for flags in "" "--xla_gpu_force_compilation_parallelism=16"; do
    name="r${round}${flags:+_parallel}"
    XLA_FLAGS="$flags" chunk "$name"
    echo "| $round | ${flags:-(default)} | $(compile_s "$name") |"
  done
done
TF_CPP_MIN_LOG_LEVEL=0 TF_CPP_VMODULE=gpu_compiler=1,compile_module_to_llvm_ir=1 chunk timers
echo "XLA's phases for jit_chunk (with the timers on, compile $(compile_s timers) s):"
grep -E "(RunHloPasses|RunBackend|IR emission) for jit_chunk time" "$OUT/timers.txt" \
  | sed -E 's/.*\] //; s/ \(cumulative.*//'
echo "autotuning's extracted fusions compiled: $(grep -c 'IR emission for extracted' "$OUT/timers.txt")"
