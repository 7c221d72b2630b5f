"""What a task of one's own costs: env steps/s of each robot beside the same robot with an
event's extra reward term: stepping (random actions, the preset's num_envs, at least 4,096 on a
GPU) and training (the preset's chunk, once the replay has filled), the medians of --rounds
rounds, robot and event timed in turns so that the machine's drift falls on both.

    python benchmarks/event_cost.py                       # the 2-core CPU: cpu presets
    python benchmarks/event_cost.py --kind gpu            # one GPU: gpu presets
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import common

PAIRS = (("Hopper", "mjx_hopper.envs.events:HighJump"),
         ("Ant", "mjx_hopper.envs.events:AntLongJump"))


def stepper(env, num_envs: int, steps: int = 50) -> common.Timed:
  """Compiled calls of `steps` random-action steps of `num_envs` envs."""
  import jax

  from mjx_hopper import rollout
  init, run = rollout.make_stepper(env, num_envs, steps)
  key = jax.random.PRNGKey(0)
  return common.Timed(run, init(key), key)


def trainer(cfg) -> common.Timed:
  """`cfg`'s compiled training chunk, once learning has started."""
  import jax

  from mjx_hopper import loop, train
  built = loop.build(cfg)
  timed = common.Timed(built.train_chunk, built.init(jax.random.PRNGKey(0)))
  while train.iterations(timed.state) * cfg.train.num_envs * cfg.train.unroll_length < (
      cfg.train.min_replay + cfg.train.steps_per_iteration):
    timed()
  timed()
  return timed


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--kind", default="cpu", help="the presets: cpu or gpu")
  p.add_argument("--rounds", type=int, default=5)
  p.add_argument("--robots", default="Hopper,Ant")
  p.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1)
  args = p.parse_args()
  import mjx_hopper
  os.environ["XLA_FLAGS"] = mjx_hopper.xla_flags_with_cpu_devices(args.cpu_devices)
  mjx_hopper.use_compile_cache()
  import jax

  from mjx_hopper import presets
  device = jax.local_devices()[0]
  print(f"{device.platform} {device.device_kind} x {len(jax.local_devices())}, "
        f"{platform.node()}, {time.strftime('%Y-%m-%d')}, {args.kind} presets, "
        f"{args.rounds} rounds")
  print("| robot | event | stepping: robot | event | ratio | training: robot | event | ratio |")
  print("|---|---|---|---|---|---|---|---|")
  for robot, event in PAIRS:
    if robot not in args.robots.split(","):
      continue
    # The same episodes (an event may have its own length) for both.
    cfgs = [presets.run_config(task, args.kind, episode_steps=1000) for task in (robot, event)]
    num_envs = cfgs[0].train.num_envs if args.kind == "cpu" else max(4096, cfgs[0].train.num_envs)
    steps = [stepper(c.make_env(), num_envs) for c in cfgs]
    chunks = [trainer(c) for c in cfgs]
    rates = {"step": ([], []), "train": ([], [])}
    per_chunk = cfgs[0].train.steps_per_iteration * cfgs[0].train.iterations_per_chunk
    for _ in range(args.rounds):
      for i in (0, 1):
        rates["step"][i].append(num_envs * 50 / steps[i]())
        rates["train"][i].append(per_chunk / chunks[i]())
    med = {k: [statistics.median(v[i]) for i in (0, 1)] for k, v in rates.items()}
    print(f"| {robot} | {event.split(':')[-1]} | {med['step'][0]:,.0f} | {med['step'][1]:,.0f} | "
          f"{med['step'][1] / med['step'][0]:.3f} | {med['train'][0]:,.0f} | "
          f"{med['train'][1]:,.0f} | {med['train'][1] / med['train'][0]:.3f} |", flush=True)


if __name__ == "__main__":
  main()
