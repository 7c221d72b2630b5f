"""The shipped policies: each robot given trained with its preset until an evaluation reaches
its score plus a margin, or its time cap; its best policy exported as ROBOT.npz, with the
robot's fingerprint, and that file evaluated again. Writes the files into
mjx_hopper/faces/pretrained/ (or where $MJX_HOPPER_RESULTS points: gpu.sh brings that folder back)
and each robot's record to benchmarks/results/pretrained_ROBOT.json.

    bash benchmarks/gpu.sh "python benchmarks/pretrain.py Hopper Walker2D HalfCheetah"
    python benchmarks/pretrain.py Hopper --kind cpu --steps 20000 --target 0   # a check on CPU
"""

from __future__ import annotations

import gc
import os
import shlex
import sys

import common

EPISODES, EVAL_SEED = 16, 1  # the exported file's check


def train_until_score(robot: str, seed: int, goal: float, args) -> dict:
  """One seed of `robot` trained until an evaluation reaches `goal` or the time cap; its run's
  folder, best evaluation and last env steps."""
  from mjx_hopper.run import loop
  from mjx_hopper.settings import presets
  out = os.path.join(args.out, robot, f"seed_{seed}")
  if os.path.exists(os.path.join(out, "checkpoints")):  # a run there would resume instead
    raise SystemExit(f"pretrain: {out} already holds a run; choose another --out or remove it")
  cfg = presets.run_config(robot, args.kind, seed=seed, total_env_steps=args.steps or 10**12,
                           max_minutes=args.minutes, stop_at_return=goal, eval_episodes=20,
                           out_dir=out, checkpoint_minutes=10**6)
  loop.run(cfg, progress=False)
  rows = common.evaluations(os.path.join(out, "log.csv"))[0]
  best = max(rows, key=lambda r: r["eval_return"])
  return {"seed": seed, "checkpoints": os.path.join(out, "checkpoints"),
          "best_eval_return": best["eval_return"], "env_steps": best["env_steps"],
          "trained_env_steps": rows[-1]["env_steps"], "wall_s": rows[-1]["wall_s"],
          "reached": best["eval_return"] >= goal}


def pretrain(robot: str, args, files: str) -> dict:
  """Trains `robot` (the seeds in turn, until one reaches the goal), exports its best policy to
  FILES/ROBOT.npz, evaluates that file, writes into it the robot's fingerprint and this record,
  and returns the record."""
  from mjx_hopper import envs
  from mjx_hopper.faces import export
  from mjx_hopper.settings import presets
  preset = presets.get(robot, args.kind)
  target = preset.target if args.target is None else args.target
  goal = target + args.margin * abs(target)
  for seed in args.seeds:
    run = train_until_score(robot, seed, goal, args)
    gc.collect()  # the run's replay, before the next robot's
    if run["reached"]:
      break
  path = os.path.join(files, f"{robot}.npz")
  export.export_checkpoint(run.pop("checkpoints"), path)
  command = shlex.join(["python", "benchmarks/pretrain.py", robot, *_settings(args),
                        "--seeds", str(run["seed"])])
  returns = export.evaluate_file(path, episodes=EPISODES, seed=EVAL_SEED)["return"]
  record = {"robot": robot, "kind": args.kind, "target": target, "goal": goal, **run,
            "command": command, "commit": common.commit(), "return": float(returns.mean()),
            "return_std": float(returns.std()), "episodes": EPISODES, "eval_seed": EVAL_SEED,
            "at_target": float(returns.mean()) >= target}
  policy = export.load(path)
  policy.meta.update(fingerprint=export.fingerprint(envs.make(robot)), pretrained=dict(record))
  export.save(policy, path)
  return {**record, "file_bytes": os.path.getsize(path)}


def _settings(args) -> list[str]:
  """The command-line settings that shaped a robot's training, as flags."""
  out = ["--kind", args.kind, "--margin", f"{args.margin:g}", "--minutes", f"{args.minutes:g}"]
  for flag, value in (("--steps", args.steps), ("--target", args.target)):
    if value is not None:
      out += [flag, f"{value:g}"]
  return out


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("robots", nargs="+", help="robots, trained one after another")
  p.add_argument("--kind", default="gpu", help="the robot preset: gpu or cpu")
  p.add_argument("--seeds", default="0",
                 help="seeds tried in turn until one reaches the goal (comma-separated)")
  p.add_argument("--margin", type=float, default=0.03,
                 help="the goal over the robot's score, as a fraction of it")
  p.add_argument("--target", type=float, default=None, help="default: the preset's score")
  p.add_argument("--minutes", type=float, default=3.0, help="each seed's time cap")
  p.add_argument("--steps", type=int, default=None, help="also stop each seed at these env steps")
  p.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1)
  p.add_argument("--out", default="runs/pretrain", help="the training runs' folder")
  args = p.parse_args()
  args.seeds = [int(s) for s in args.seeds.split(",")]
  import mjx_hopper  # its own imports only: JAX starts later
  mjx_hopper.setup(cpu_devices=args.cpu_devices)
  from mjx_hopper import envs
  from mjx_hopper.faces import export
  from mjx_hopper.settings import presets
  if not set(args.robots) <= set(envs.tasks.BUILT_IN) or args.kind not in presets.KINDS:
    raise SystemExit(f"pretrain: the robots are {list(envs.tasks.BUILT_IN)} and the presets "
                     f"{list(presets.KINDS)}; got {args.robots} and {args.kind!r}")
  files = os.environ.get("MJX_HOPPER_RESULTS") or export.PRETRAINED
  records = []
  for robot in args.robots:
    records.append(pretrain(robot, args, files))
    common.write_results(f"pretrained_{robot}", records[-1])
  print(common.table(
      ["robot", "seed", "env steps", "best evaluation", "file's return", "score", "bytes"],
      [[r["robot"], r["seed"], f"{r['env_steps']:,}", f"{r['best_eval_return']:.0f}",
        f"{r['return']:.0f} +- {r['return_std']:.0f}", f"{r['target']:g}", r["file_bytes"]]
       for r in records]))
  missed = [r["robot"] for r in records if not r["at_target"]]
  if missed:
    sys.exit(f"pretrain: below the score: {missed}; do not ship these files")


if __name__ == "__main__":
  main()
