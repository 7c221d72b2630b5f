#!/usr/bin/env bash
# XLA:GPU's command buffers (CUDA graphs) on the learner, a sweep and Hopper's time to score. Our
# GPU programs are latency-bound: an update is ~170 kernels of a few microseconds, an
# evaluation 1,000 sequential env steps at batch 20. XLA records runs of kernels into CUDA graphs;
# by default not loops (scan, while) or conditionals, which split the graphs. Each flag set runs,
# in fresh processes with empty compile caches:
#   the gpu preset's update (batch 8,192, float32; learner_throughput.py),
#   a 1- and a 16-member sweep (sweep_throughput.py, as BENCHMARKS' "Sweeps"),
#   Hopper's gpu preset, seed 0, to 2,500 (time_to_score.py): its env steps/s, how long each
#   evaluation took (its log row's clock less the chunk's before it), its time to the target.
# On the GPU:
#   bash benchmarks/gpu.sh "bash benchmarks/command_buffers.sh"
set -uo pipefail
OUT_DIR=${OUT_DIR:-runs/command_buffers}
SETS=${SETS:-default none loops}
mkdir -p "$OUT_DIR"
flags() {  # NAME: its XLA_FLAGS
  case $1 in
    default) echo "" ;;
    none) echo "--xla_gpu_enable_command_buffer=" ;;
    loops) echo "--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL --xla_gpu_graph_min_graph_size=1" ;;
    unrolled) echo "--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL --xla_gpu_graph_min_graph_size=1 --xla_gpu_command_buffer_unroll_loops=true" ;;
    *) echo "command_buffers.sh: unknown set $1 (default, none, loops, unrolled)" >&2; exit 2 ;;
  esac
}
fresh() {  # COMMAND...: run with an empty compile cache of its own
  local cache status
  cache=$(mktemp -d)
  MJX_HOPPER_JAX_CACHE=$cache "$@"
  status=$?
  rm -rf "$cache"
  return $status
}
for name in $SETS; do
  export XLA_FLAGS
  XLA_FLAGS=$(flags "$name") || exit 2
  echo "== $name: XLA_FLAGS='$XLA_FLAGS'"
  fresh timeout 150 python benchmarks/learner_throughput.py --presets gpu --batch 8192 \
    --updates 100 --devices 1 --json "$OUT_DIR/learner_$name.json" >"$OUT_DIR/learner_$name.txt" 2>&1
  fresh timeout 150 python benchmarks/sweep_throughput.py --preset gpu --num-envs 512 \
    --batch-size 1024 --replay-size 1000000 --chunk 10 --chunks 3 --members 1,16 --cpu-devices 1 \
    --out "$OUT_DIR/sweep_$name.json" >"$OUT_DIR/sweep_$name.txt" 2>&1
  timeout 150 python benchmarks/time_to_score.py Hopper --kind gpu --cpu-devices 1 --seeds 0 \
    --minutes 1.6 --no-compile-cache --out "$OUT_DIR/hopper_$name" >"$OUT_DIR/hopper_$name.txt" 2>&1
  python - "$OUT_DIR" "$name" <<'EOF'
import csv, json, os, statistics, sys
out, name = sys.argv[1:]
def load(path, get):
  try:
    with open(path) as f:
      return get(json.load(f))
  except Exception as error:  # a run that failed: say where its output is
    return f"failed ({type(error).__name__}; {path[:-5]}.txt)"
learner = load(f"{out}/learner_{name}.json", lambda d: round(d["rows"][0]["updates_per_s"]))
sweep = load(f"{out}/sweep_{name}.json",
             lambda d: {r["members"]: round(r["env_steps_per_s"]) for r in d["rows"]})
hopper = load(f"{out}/hopper_{name}/summary.json", lambda d: d["seeds"]["0"])
evals = []
try:
  with open(f"{out}/hopper_{name}/seed_0/log.csv") as f:
    rows = list(csv.DictReader(f))
  for before, row in zip(rows, rows[1:]):
    if row["kind"] == "eval" and before["kind"] == "train":
      evals.append(float(row["wall_s"]) - float(before["wall_s"]))
except OSError:
  pass
train = [r for r in rows if r["kind"] == "train"] if evals else []
rates = [float(r["steps_per_s"]) for r in train[2:]]
print(json.dumps({"set": name, "flags": os.environ.get("XLA_FLAGS", ""),
                  "learner_updates_per_s": learner, "sweep_env_steps_per_s": sweep,
                  "hopper_median_env_steps_per_s": round(statistics.median(rates)) if rates else None,
                  "hopper_eval_s": [round(e, 2) for e in evals],
                  "hopper_first_train_row_s": float(train[0]["wall_s"]) if train else None,
                  "hopper": hopper if isinstance(hopper, str) else
                  {k: hopper.get(k) for k in ("target_wall_s", "target_env_steps", "best_return")}}))
EOF
done
