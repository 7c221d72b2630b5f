"""Learning curves: evaluation return against env steps and wall-clock seconds (compile
included), for several seeds, with time-to-score.

    python benchmarks/learning.py --agent d4pg --seeds 0,1,2 --sequential --minutes 30   # CPU
    python benchmarks/learning.py --preset gpu --batch-size 1024 --cpu-devices 1 ...      # GPU
                          # (through benchmarks/gpu.sh; docs/benchmark-history.md has the runs)

Each seed is a `mjx_hopper.loop.run` in its own process; the seeds run at the same time, sharing
the machine, or with --sequential one after another. Writes OUT/seed_N/log.csv,
OUT/summary.json and OUT/curves.png.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time

import time_to_score  # this folder's: reading log.csv, the per-seed figures and their plot


def one_seed(args, seed: int) -> None:
  from mjx_hopper import cli
  cli.main(["--cpu-devices", str(args.cpu_devices), "train", "--env", args.env,
            "--agent", args.agent, "--preset", args.preset, "--steps", str(args.max_steps),
            "--max-minutes", str(args.minutes), "--num-envs", str(args.num_envs),
            "--unroll-length", str(args.unroll_length), "--batch-size", str(args.batch_size),
            "--replay-ratio", str(args.replay_ratio), "--min-replay", str(args.min_replay),
            "--chunk", str(args.chunk), "--eval-every", str(args.eval_every),
            "--seed", str(seed), "--out", os.path.join(args.out, f"seed_{seed}"),
            "--no-progress", "--log-every", "60", "--checkpoint-minutes", "1000"]
           + sum((["--set", s] for s in args.set), []))


def evaluations(args, seed: int) -> list[dict]:
  """A seed's evaluation rows so far (time_to_score.evaluations), none before its log exists."""
  path = os.path.join(args.out, f"seed_{seed}", "log.csv")
  return time_to_score.evaluations(path).get(0, []) if os.path.exists(path) else []


def reached(args, seed: int) -> bool:
  try:
    return any(r["eval_return"] >= args.target for r in evaluations(args, seed))
  except (ValueError, KeyError):  # a row being written as we read
    return False


def summarise(args, seeds: list[int]) -> dict:
  summary = {"env": args.env, "agent": args.agent, "preset": args.preset, "target": args.target,
             "seeds": {seed: time_to_score.summarise(evaluations(args, seed), args.target)
                       for seed in seeds}}
  time_to_score.plot(summary["seeds"], args.env, args.target,
                     f"{args.agent} ({args.preset}){': ' + args.label if args.label else ''}",
                     os.path.join(args.out, "curves.png"))
  with open(os.path.join(args.out, "summary.json"), "w") as f:
    json.dump(summary, f, indent=1)
  return summary


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--env", default="Hopper")
  p.add_argument("--agent", default="d4pg")
  p.add_argument("--preset", default="cpu")
  p.add_argument("--set", action="append", default=[])
  p.add_argument("--seeds", default="0,1,2")
  p.add_argument("--minutes", type=float, default=30.0, help="wall-clock budget of each seed")
  p.add_argument("--max-steps", type=int, default=10**9)
  p.add_argument("--num-envs", type=int, default=512)
  p.add_argument("--unroll-length", type=int, default=4)
  p.add_argument("--batch-size", type=int, default=256)
  p.add_argument("--replay-ratio", type=float, default=4.0)
  p.add_argument("--min-replay", type=int, default=20_000)
  p.add_argument("--chunk", type=int, default=25)
  p.add_argument("--eval-every", type=int, default=200_000)
  p.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1)
  p.add_argument("--sequential", action="store_true",
                 help="run the seeds one after another, each with the machine to itself")
  p.add_argument("--target", type=float, default=2000.0)
  p.add_argument("--stop-at-target", action="store_true",
                 help="end a seed (SIGTERM: it saves and exits) once an evaluation reaches "
                      "--target, instead of running out its budget")
  p.add_argument("--label", default="")
  p.add_argument("--out", default="runs/learning")
  p.add_argument("--summarise-only", action="store_true",
                 help="only redo summary.json, curves.png and the table from OUT's logs")
  p.add_argument("--one-seed", type=int, default=None, help=argparse.SUPPRESS)
  args = p.parse_args()
  if args.one_seed is not None:
    return one_seed(args, args.one_seed)
  seeds = [int(s) for s in args.seeds.split(",")]
  if args.summarise_only:
    return report(summarise(args, seeds))
  os.makedirs(args.out, exist_ok=True)
  argv = [a for a in sys.argv[1:]]
  def start(seed):
    return subprocess.Popen([sys.executable, __file__, *argv, "--one-seed", str(seed)])
  def finish(procs: dict) -> list[int]:
    """Waits for every seed's process, stopping those that reached the target if asked."""
    while any(proc.poll() is None for proc in procs.values()):
      for seed, proc in procs.items():
        if proc.poll() is None and args.stop_at_target and reached(args, seed):
          proc.send_signal(signal.SIGTERM)
          proc.wait()
      time.sleep(2)
    return [proc.returncode for proc in procs.values()]
  if args.sequential:
    codes = [code for seed in seeds for code in finish({seed: start(seed)})]
  else:
    codes = finish({seed: start(seed) for seed in seeds})
  if any(codes):
    raise SystemExit(f"a seed failed: exit codes {codes}")
  report(summarise(args, seeds))


def report(summary: dict) -> None:
  print("| seed | best eval return | final | env steps | wall s "
        "| target reached at (env steps, s) |")
  print("|---|---|---|---|---|---|")
  for seed, s in summary["seeds"].items():
    hit = (f"{s['target_env_steps']:,}, {s['target_wall_s']:.0f}" if s["target_env_steps"]
           else "not reached")
    print(f"| {seed} | {s['best_return']:.0f} | {s['final_return']:.0f} | {s['env_steps']:,} | "
          f"{s['wall_s']:.0f} | {hit} |")


if __name__ == "__main__":
  main()
