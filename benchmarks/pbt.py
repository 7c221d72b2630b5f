"""Population-based training against the grid it starts from: per seed, the grid and PBT side
by side on one GPU (each with half its memory), the same 16 members (QUALITY), each a
`mjx-hopper sweep` process writing OUT/<run>/log.csv, for the same minutes.

    python benchmarks/pbt.py quality --minutes 4 --seeds 0 1 --label h100
    # two GPUs, a seed on each at once; then --resume for as many more --minutes (cumulative)
    python benchmarks/pbt.py quality --env HalfCheetah --target 3000 --gpus 2 --minutes 8

Figures per run (HEAD): when the population's best evaluation first reached the target (s from
the run's start, compile included; with --resume, the processes' times added), its best
evaluation, the median of the members' best, and the median chunk's env steps/s (side by side,
their ratio is PBT's overhead). Results: benchmarks/results/pbt_quality_LABEL.json.
"""

from __future__ import annotations

import csv
import os
import shutil
import statistics
import subprocess
import sys

import common

# 4 learning rates x 4 noise scales, in the gpu preset's layout where members share a GPU well.
GRID = ["--set", "learning_rate=2.5e-4,5e-4,1e-3,2e-3", "--set", "sigma=0.2,0.4,0.6,0.8"]
QUALITY = ["--preset", "gpu", "--num-envs", "512", "--batch-size", "1024", "--replay-size",
           "1000000", *GRID, "--total-env-steps", str(10**10)]
HEAD = ["seed", "run", "best to target (s)", "best return", "members' median best",
        "env steps", "env steps/s (median chunk)"]


def sweep(flags: list[str], out: str, env: dict | None = None,
          resume: bool = False) -> subprocess.Popen:
  """`mjx-hopper sweep FLAGS` in a process of its own (-P: the installed package, not the
  checkout's folder of the same name), in a fresh OUT (an old one would be resumed), or with
  `resume` continuing the run in OUT, which must hold its checkpoint."""
  if not resume:
    shutil.rmtree(out, ignore_errors=True)
  elif not os.path.isdir(os.path.join(out, "checkpoints")):
    raise SystemExit(f"--resume: {out} holds no checkpoint to continue (a fresh machine?)")
  return subprocess.Popen([sys.executable, "-P", "-m", "mjx_hopper.faces.cli", "sweep", *flags,
                           "--out-dir", out, "--no-progress", "--log-every", "30",
                           "--checkpoint-minutes", "1e4"], env={**os.environ, **(env or {})})


def population(log_csv: str, target: float) -> list:
  """[when the population's best evaluation first reached `target` (s), its best evaluation,
  the median of the members' best, env steps, the median chunk's env steps/s] of a sweep's
  log.csv. A resumed run's rows restart their wall_s: each process's is added to the last's."""
  if not os.path.exists(log_csv):
    raise SystemExit(f"{log_csv} does not exist: the run ended before its first chunk (its "
                     "compile outlasted --minutes); give it more")
  with open(log_csv) as f:
    rows = list(csv.DictReader(f))
  offset = last = 0.0
  for r in rows:
    wall = float(r["wall_s"])
    if wall < last:  # the first row of the next process
      offset += last
    last, r["wall_s"] = wall, wall + offset
  best, members = {}, {}  # env steps -> (wall_s, the population's best); member -> its best
  for r in rows:
    if r["kind"] == "eval":
      steps, ret = int(r["env_steps"]), float(r["eval_return"])
      wall, top = best.get(steps, (0.0, -float("inf")))
      best[steps] = (max(wall, r["wall_s"]), max(top, ret))
      members[r["member"]] = max(members.get(r["member"], -float("inf")), ret)
  hit = next((best[s] for s in sorted(best) if best[s][1] >= target), None)
  rates = [float(r["steps_per_s"]) for r in rows if r["kind"] == "train" and r["member"] == "0"]
  return ["not reached" if hit is None else f"{hit[0]:.0f}",
          f"{max(t for _, t in best.values()):,.0f}",
          f"{statistics.median(members.values()):,.0f}", f"{max(best):,}",
          f"{statistics.median(rates[1:]):,.0f}"]


def quality(args) -> list[list]:
  """Per seed the grid and PBT side by side on one GPU; with --gpus N, all seeds at once, seed i
  on GPU i mod N."""
  rows = []
  groups = [args.seeds] if args.gpus else [[seed] for seed in args.seeds]
  for group in groups:
    procs, runs = [], []
    for i, seed in enumerate(group):
      flags = [*QUALITY, "--env", args.env, "--seed", str(seed), "--max-minutes",
               str(args.minutes), "--eval-every", str(args.eval_every)]
      env = {"XLA_PYTHON_CLIENT_MEM_FRACTION": "0.45"}
      if args.gpus:
        env["CUDA_VISIBLE_DEVICES"] = str(i % args.gpus)
      for arm in ("grid", "pbt"):
        out = os.path.join(args.out, f"{arm}_{seed}")
        procs.append(sweep(flags + (["--pbt"] if arm == "pbt" else []), out, env, args.resume))
        runs.append((seed, arm, out))
    if any(p.wait() for p in procs):
      raise SystemExit("a run failed; see its output above")
    rows += [[seed, arm, *population(os.path.join(out, "log.csv"), args.target)]
             for seed, arm, out in runs]
    print(common.table(HEAD, rows), flush=True)  # so far, should a later seed not finish
  return rows


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("mode", choices=("quality",), help="the only mode: quality")
  p.add_argument("--minutes", type=float, default=6.0, help="each run's budget")
  p.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="its seeds")
  p.add_argument("--env", default="Hopper", help="the robot")
  p.add_argument("--target", type=float, default=2500.0, help="its target")
  p.add_argument("--eval-every", type=int, default=100_000,
                 help="env steps between evaluations (PBT steps at every second)")
  p.add_argument("--gpus", type=int, default=0,
                 help="run all seeds at once, seed i on GPU i mod GPUS")
  p.add_argument("--resume", action="store_true",
                 help="continue the runs in --out for --minutes more")
  p.add_argument("--label", default="run")
  p.add_argument("--out", default="runs/pbt")
  args = p.parse_args()
  rows = quality(args)
  text = common.table(HEAD, rows)
  print(text)
  common.write_results(f"pbt_{args.mode}_{args.label}", {"table": text, "rows": rows})


if __name__ == "__main__":
  main()
