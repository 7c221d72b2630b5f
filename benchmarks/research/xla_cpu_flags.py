"""XLA:CPU flags against each other: the time to trace and to compile a batched MJX rollout, and
its env steps/s, per robot, each measurement in a fresh process (no compile cache).

    python benchmarks/research/xla_cpu_flags.py                        # every robot, 2 devices
    python benchmarks/research/xla_cpu_flags.py --envs Hopper --repeats 3 \
        --variants="--xla_cpu_use_fusion_emitters=true;--xla_cpu_use_fusion_emitters=false"

Variants are `;`-separated XLA_FLAGS strings; the first is the reference of the ratio columns,
and an empty one is XLA's default.
Runs are interleaved (robot by robot, variant by variant, repeat by repeat), so that the
machine's drift falls on every variant alike; the table gives the median over repeats. Trace is
`jit(...).lower` (Python: MJX building the program), compile is XLA's `.compile()`, and the
rate is the median of 3 timed calls of T = 50 steps of N auto-resetting envs after a warm-up.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time

ROBOTS = "Hopper,Walker2D,HalfCheetah,Ant,Humanoid"
# XLA's default and the tests' setting (tests/conftest.py).
VARIANTS = "--xla_cpu_use_fusion_emitters=true;--xla_cpu_use_fusion_emitters=false"


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  p.add_argument("--envs", default=ROBOTS)
  p.add_argument("--variants", default=VARIANTS, help="';'-separated XLA_FLAGS strings")
  p.add_argument("--num-envs", type=int, default=256)
  p.add_argument("--devices", type=int, default=2)
  p.add_argument("--repeats", type=int, default=1)
  p.add_argument("--out", default="benchmarks/results/xla_cpu_flags.json")
  p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
  args = p.parse_args()
  if args.worker:
    # env_throughput.py is in benchmarks/, this script's parent folder.
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from env_throughput import time_stepper
    from mjx_hopper import envs
    print(json.dumps(time_stepper(envs.make(args.envs), args.num_envs, steps=50)))
    return
  from mjx_hopper import envs
  robots, variants = args.envs.split(","), [v.strip() for v in args.variants.split(";")]
  unknown = sorted(set(robots) - set(envs.list_envs()))
  if unknown or args.repeats < 1 or args.devices < 1:
    raise SystemExit(f"need known --envs (unknown: {unknown}; valid: {envs.list_envs()}), "
                     f"--repeats >= 1 and --devices >= 1 (got {args.repeats}, {args.devices})")
  results = {(r, v): [] for r in robots for v in variants}
  for repeat in range(args.repeats):
    for robot in robots:
      for variant in variants:
        flags = f"--xla_force_host_platform_device_count={args.devices} {variant}"
        out = subprocess.run([sys.executable, __file__, "--worker", "--envs", robot,
                              "--num-envs", str(args.num_envs)], check=True, text=True,
                             stdout=subprocess.PIPE, env=dict(os.environ, XLA_FLAGS=flags))
        results[robot, variant].append(json.loads(out.stdout.strip().splitlines()[-1]))
        row = results[robot, variant][-1]
        print(f"  [{repeat + 1}/{args.repeats}] {robot} {variant or '(default)'}: trace "
              f"{row['trace_s']:.1f} s, compile {row['compile_s']:.1f} s, "
              f"{row['env_steps_per_s']:,.0f} env steps/s", file=sys.stderr, flush=True)
  rows = []
  for robot in robots:
    for variant in variants:
      runs = results[robot, variant]
      rows.append({"env": robot, "xla_flags": variant, "devices": args.devices,
                   "batch": args.num_envs, "repeats": len(runs),
                   **{k: statistics.median(run[k] for run in runs)
                      for k in ("trace_s", "compile_s", "env_steps_per_s")}})
  lines = ["| env | XLA_FLAGS | trace (s) | compile (s) | env steps/s | compile ÷ first "
           "| steps/s ÷ first |", "|---|---|---|---|---|---|---|"]
  for row in rows:
    first = next(r for r in rows if r["env"] == row["env"] and r["xla_flags"] == variants[0])
    lines.append(f"| {row['env']} | `{row['xla_flags'] or '(default)'}` | {row['trace_s']:.1f} | "
                 f"{row['compile_s']:.1f} | {row['env_steps_per_s']:,.0f} | "
                 f"{row['compile_s'] / first['compile_s']:.2f} | "
                 f"{row['env_steps_per_s'] / first['env_steps_per_s']:.2f} |")
  print(f"{platform.node()}, {os.cpu_count()} CPUs, {args.devices} XLA devices, batch "
        f"{args.num_envs}, median of {args.repeats}\n" + "\n".join(lines))
  os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
  with open(args.out, "w") as f:
    json.dump({"date": time.strftime("%Y-%m-%d"), "machine": platform.node(),
               "cpus": os.cpu_count(), "rows": rows}, f, indent=1)


if __name__ == "__main__":
  main()
