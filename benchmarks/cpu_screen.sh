#!/usr/bin/env bash
# Screens settings of a robot's cpu preset on one GPU, by env steps: each ARM, "LABEL=ROBOT
# [time_to_score.py arguments]", trains seeds 0-3 as one sweep (--kind cpu --at-once) in its own
# process, every arm at once sharing the GPU, until ENV_STEPS or MINUTES. The return after given
# env steps and updates does not depend on the machine, so the 2-core CPU's time follows from its
# own env steps/s, measured there. Prints, per arm and seed, the env steps at which evaluations
# first reached each of THRESHOLDS; results in runs/screen/LABEL/summary.json.
#   bash benchmarks/gpu.sh "bash benchmarks/cpu_screen.sh 'preset=Walker2D' \
#     'tuned=Walker2D --set learning_rate=2e-3 --set policy_layers=(128,128)'"
set -uo pipefail
ENV_STEPS=${ENV_STEPS:-8000000} MINUTES=${MINUTES:-8.4} THRESHOLDS=${THRESHOLDS:-1000,2000,2500}
export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.12}  # arms share it
mkdir -p runs/screen
for arm in "$@"; do
  label=${arm%%=*}
  # shellcheck disable=SC2086  # the arm's arguments split into words
  python benchmarks/time_to_score.py ${arm#*=} --kind cpu --at-once --seeds 0,1,2,3 \
    --cpu-devices 2 --env-steps "$ENV_STEPS" --minutes "$MINUTES" --out "runs/screen/$label" \
    >"runs/screen/$label.txt" 2>&1 &
done
wait
python3 - "$THRESHOLDS" "$@" <<'PY'
import json, sys
thresholds = [float(t) for t in sys.argv[1].split(",")]
for arm in sys.argv[2:]:
  label = arm.split("=", 1)[0]
  try:
    seeds = json.load(open(f"runs/screen/{label}/summary.json"))["seeds"]
  except (OSError, ValueError, KeyError) as e:
    print(f"{label}: no summary ({e}); see runs/screen/{label}.txt")
    continue
  for seed, s in seeds.items():
    firsts = [next((f"{p['env_steps'] / 1e6:.2f}M" for p in s["curve"]
                    if p["eval_return"] >= t), "-") for t in thresholds]
    print(f"{arm} | seed {seed} | " + " | ".join(
        f"{t:g} at {f}" for t, f in zip(thresholds, firsts))
        + f" | best {s['best_return']:.0f} | {s['env_steps'] / 1e6:.2f}M env steps")
PY
