#!/usr/bin/env bash
# The gpu preset's training chunk (Hopper, D4PG, one member, 512 envs, batch 1,024): its compile
# time with XLA's default flags and with --xla_gpu_force_compilation_parallelism=16, two rounds,
# each run a fresh process with an empty compile cache; then one more run with XLA's phase
# timers logged (RunHloPasses, RunBackend, IR emission), summed up at the end. On the GPU:
#   bash benchmarks/gpu.sh "bash benchmarks/compile_flags.sh"
# (XLA of jax 0.11.2 no longer knows --xla_gpu_enable_llvm_module_compilation_parallelism.)
set -uo pipefail
OUT=${OUT:-runs/compile_flags}
mkdir -p "$OUT"
chunk() {
  MJX_HOPPER_JAX_CACHE=$(mktemp -d) python benchmarks/sweep_throughput.py --preset gpu \
    --num-envs 512 --batch-size 1024 --replay-size 100000 --chunk 10 --chunks 1 --members 1 \
    --cpu-devices 1 --out "$OUT/$1.json"
}
echo "| round | XLA_FLAGS | chunk's compile (s) |"
echo "|---|---|---|"
for round in 1 2; do
  for flags in "" "--xla_gpu_force_compilation_parallelism=16"; do
    seconds=$(XLA_FLAGS="$flags" chunk "r$round" 2>/dev/null | tail -1 | cut -d'|' -f4)
    echo "| $round | ${flags:-(default)} |$seconds|"
  done
done
TF_CPP_MIN_LOG_LEVEL=0 TF_CPP_VMODULE=gpu_compiler=1,compile_module_to_llvm_ir=1 chunk timers \
  >"$OUT/timers.txt" 2>&1
echo "XLA's phases for jit_chunk:"
grep -E "(RunHloPasses|RunBackend|IR emission) for jit_chunk time" "$OUT/timers.txt" \
  | sed -E 's/.*\] //; s/ \(cumulative.*//'
