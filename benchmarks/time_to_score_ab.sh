#!/usr/bin/env bash
# Time to score, this tree against an older commit, seed by seed in turn (each seed alone and
# compiled afresh, new then old), so that both arms share the machine's drift. On the GPU:
#   OLD=4763dab SEEDS="0 1 2" ARGS="Hopper --kind gpu --cpu-devices 1 --minutes 1.3" \
#     bash benchmarks/gpu.sh "bash benchmarks/time_to_score_ab.sh"
# (gpu.sh runs on the device's copy of the tree, which has no git history: make the old arm's
# sources here first, with the same OLD, and they travel as oldsrc/:
#   OLD=4763dab bash benchmarks/time_to_score_ab.sh --prepare
# then remove oldsrc/ afterwards.) Each run's time_to_score.py output and folder go to
# runs/ab/{new,old}_SEED, and one JSON line per run to stdout: its time and env steps to the
# target, its first train row (the run's clock), its median env steps/s after the first two
# chunks, and its evaluations as [env steps, wall s, return, s from due to logged].
set -uo pipefail
if [ "${1:-}" = --prepare ]; then
  rm -rf oldsrc && mkdir oldsrc
  git archive "$OLD" mjx_hopper agents envs pyproject.toml README.md benchmarks/time_to_score.py \
    benchmarks/common.py | tar -x -C oldsrc
  exit
fi
[ -d oldsrc ] || { echo "time_to_score_ab.sh: no oldsrc/; run it with --prepare first" >&2; exit 2; }
python3 -m pip install -q --no-deps --no-build-isolation --no-compile --target /tmp/old ./oldsrc \
  || exit 1
mkdir -p runs/ab
summary() {  # FOLDER
  python3 - "$1" <<'PY'
import csv, json, sys
out = sys.argv[1]
seed, r = next(iter(json.load(open(f"{out}/summary.json"))["seeds"].items()))
rows = list(csv.DictReader(open(f"{out}/seed_{seed}/log.csv")))
train = [x for x in rows if x["kind"] == "train"]
due = {int(x["env_steps"]): float(x["wall_s"]) for x in train}
rates = sorted(float(x["steps_per_s"]) for x in train[2:])
print(json.dumps({
    "run": out, "target_wall_s": r["target_wall_s"], "target_env_steps": r["target_env_steps"],
    "first_train_row_s": round(float(train[0]["wall_s"]), 1),
    "median_env_steps_per_s": round(rates[len(rates) // 2]) if rates else None,
    "evals": [[int(x["env_steps"]), round(float(x["wall_s"]), 1), round(float(x["eval_return"])),
               round(float(x["wall_s"]) - due[int(x["env_steps"])], 2)]
              for x in rows if x["kind"] == "eval"]}))
PY
}
for s in $SEEDS; do
  # shellcheck disable=SC2086
  python benchmarks/time_to_score.py $ARGS --seeds "$s" --no-compile-cache --out "runs/ab/new_$s" \
    >"runs/ab/new_$s.txt" 2>&1 && summary "runs/ab/new_$s"
  # shellcheck disable=SC2086
  PYTHONPATH=/tmp/old:${PYTHONPATH:-} python oldsrc/benchmarks/time_to_score.py $ARGS --seeds "$s" \
    --no-compile-cache --out "runs/ab/old_$s" >"runs/ab/old_$s.txt" 2>&1 && summary "runs/ab/old_$s"
done
