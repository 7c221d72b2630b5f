"""Trainer scaling: the whole compiled trainer's env steps/s and updates/s as the number of envs
and the batch size grow, for one robot and agent config, on one device.

    python benchmarks/trainer_scaling.py --env Hopper --points 512:1024,2048:8192 --updates 2
    bash benchmarks/gpu.sh "python benchmarks/trainer_scaling.py --env Hopper --updates 2 \
      --chunk 20 --chunks 3 --points 512:1024,4096:8192,16384:32768,16384:65536"   # on a GPU

Each point ENVS:BATCH is a `train.make_trainer` with ENVS envs stepped once per iteration
(unroll 1) and `--updates` learner updates of BATCH transitions per iteration (replay ratio
updates * BATCH / ENVS), learning from the first iteration, timed over `--chunks` chunks after a
warm-up chunk. "collect only" is the same trainer with learning off (the env step, the policy's
actions and the replay insert): the rest of an iteration is the learner, so "update ms" is
(iteration - collect) / updates. Compile is XLA's compile of the chunk (trace excluded).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import os
import platform
import time


def timed_chunks(trainer, state, chunks: int) -> tuple[float, float]:
  """(compile seconds, seconds per iteration) of `trainer`'s chunk from `state`."""
  import jax
  lowered = trainer.train_chunk.lower(state)
  start = time.perf_counter()
  compiled = lowered.compile()
  compile_s = time.perf_counter() - start
  state, metrics = compiled(state)       # warm-up
  jax.block_until_ready(metrics)
  start = time.perf_counter()
  for _ in range(chunks):
    state, metrics = compiled(state)
  jax.block_until_ready(metrics)
  return compile_s, (time.perf_counter() - start) / (chunks * trainer.config.iterations_per_chunk)


def measure(args, envs: int, batch: int, collect_s: dict) -> dict:
  import jax

  from mjx_hopper import agents, envs as envs_lib, train

  env = envs_lib.make(args.env)
  agent = agents.make(args.agent, env.observation_size, env.action_size,
                      agents.config(args.agent, args.preset, **args.overrides))
  rows = 2 * args.chunk * (args.chunks + 1)

  def trainer_state(learning: bool):
    cfg = train.TrainConfig(num_envs=envs, unroll_length=1, batch_size=batch,
                            replay_ratio=args.updates * batch / envs,
                            replay_size=rows * envs,
                            min_replay=envs if learning else rows * envs,
                            iterations_per_chunk=args.chunk)
    trainer = train.make_trainer(env, agent, cfg, devices=jax.local_devices()[:1])
    return trainer, trainer.init(jax.random.PRNGKey(0))

  if envs not in collect_s:
    collect_s[envs] = timed_chunks(*trainer_state(False), args.chunks)[1]
  compile_s, iteration_s = timed_chunks(*trainer_state(True), args.chunks)
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
  args.overrides = {}
  for pair in args.set:
    name, _, value = pair.partition("=")
    args.overrides[name] = ast.literal_eval(value)
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
