"""Trainer scaling: the whole compiled trainer's env steps/s and updates/s as the number of envs
and the batch size grow, for one robot and agent config, on one device.

    python benchmarks/trainer_scaling.py --env Hopper --points 512:1024,2048:8192 --updates 2

A point ENVS:BATCH steps ENVS envs once and makes --updates updates of BATCH per iteration,
learning from the first, timed over --chunks chunks after a warm-up; "collect only" is the same
trainer with learning off, "update ms" the rest of an iteration per update, compile the chunk's
(trace excluded). BENCHMARKS.md, "Trainer scaling", has the GPU's command.
"""

from __future__ import annotations

import argparse
import json
import os
import platform

import common


def measure(args, envs: int, batch: int, collect_s: dict) -> dict:
  import jax

  from mjx_hopper import agents, envs as envs_lib, train

  env = envs_lib.make(args.env)
  agent = agents.make(args.agent, env.observation_size, env.action_size,
                      agents.config(args.agent, args.preset, **args.overrides))
  rows = 2 * args.chunk * (args.chunks + 1)

  def timed_trainer(learning: bool) -> common.Timed:
    cfg = train.TrainConfig(num_envs=envs, unroll_length=1, batch_size=batch,
                            replay_ratio=args.updates * batch / envs, replay_size=rows * envs,
                            min_replay=envs if learning else rows * envs,
                            iterations_per_chunk=args.chunk)
    trainer = train.make_trainer(env, agent, cfg, devices=jax.local_devices()[:1])
    return common.Timed(trainer.train_chunk, trainer.init(jax.random.PRNGKey(0)))

  iterations = args.chunks * args.chunk
  if envs not in collect_s:
    collect_s[envs] = timed_trainer(False)(args.chunks) / iterations
  timed = timed_trainer(True)
  compile_s, iteration_s = timed.compile_s, timed(args.chunks) / iterations
  device = jax.local_devices()[0]
  stats = device.memory_stats() if device.platform == "gpu" else None
  return {"env": args.env, "envs": envs, "batch": batch, "updates_per_iteration": args.updates,
          "compile_s": compile_s, "iteration_ms": 1e3 * iteration_s,
          "collect_ms": 1e3 * collect_s[envs],
          "update_ms": 1e3 * max(iteration_s - collect_s[envs], 0.0) / args.updates,
          "env_steps_per_s": envs / iteration_s, "updates_per_s": args.updates / iteration_s,
          "collect_env_steps_per_s": envs / collect_s[envs],
          "peak_memory_gb": stats["peak_bytes_in_use"] / 1e9 if stats else None,
          "platform": device.platform, "device": device.device_kind}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  p.add_argument("--env", default="Hopper")
  p.add_argument("--agent", default="d4pg")
  p.add_argument("--preset", default="gpu")
  p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                 help="an agent setting, e.g. num_critics=2 or critic_layers=(1024,512,256)")
  p.add_argument("--points", default="512:1024,2048:4096,8192:16384,16384:32768",
                 help="comma-separated ENVS:BATCH")
  p.add_argument("--updates", type=int, default=2, help="learner updates per iteration")
  p.add_argument("--chunk", type=int, default=20, help="iterations per chunk")
  p.add_argument("--chunks", type=int, default=3, help="timed chunks")
  p.add_argument("--json", help="also append the rows to this JSON file")
  args = p.parse_args()
  from mjx_hopper import cli
  args.overrides = cli._overrides(args.set)
  points = [tuple(int(x) for x in point.split(":")) for point in args.points.split(",")]
  collect_s, rows = {}, []
  print(f"{args.env}, {args.agent} ({args.preset}{', ' if args.overrides else ''}"
        f"{', '.join(args.set)}), {args.updates} updates per iteration, {platform.node()}")
  print("| envs | batch | env steps/s | updates/s | samples/s | collect only, env steps/s "
        "| update ms | compile s | peak GB |")
  print("|---|---|---|---|---|---|---|---|---|")
  for envs, batch in points:
    row = measure(args, envs, batch, collect_s)
    rows.append(row)
    memory = f"{row['peak_memory_gb']:.1f}" if row["peak_memory_gb"] is not None else "-"
    print(f"| {envs:,} | {batch:,} | {row['env_steps_per_s']:,.0f} | {row['updates_per_s']:,.1f} "
          f"| {row['updates_per_s'] * batch:,.0f} | {row['collect_env_steps_per_s']:,.0f} "
          f"| {row['update_ms']:.2f} | {row['compile_s']:.1f} | {memory} |", flush=True)
  if args.json:
    saved = json.load(open(args.json)) if os.path.exists(args.json) else []
    with open(args.json, "w") as f:
      json.dump(saved + [{**r, "settings": args.set} for r in rows], f, indent=1)


if __name__ == "__main__":
  main()
