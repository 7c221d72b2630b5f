"""What one learner update costs on the CPU inside the trainer, against the same update alone.

    python benchmarks/research/cpu_update_cost.py            # Hopper, D4PG's cpu preset

Inside the trainer an update's cost is the slope of the chunk's time per iteration over the
updates per iteration: the cpu layout (512 envs x unroll 4, batch 256) at replay ratio 4 and 8
(32 and 64 updates of 256 per 2,048 env steps), and with learning off (min_replay =
replay_size) for the collection alone. Alone it is a jitted scan of 8 (sample + update) on the
same agent state and replay buffer. One CPU device (the trainer's rate on two devices was
measured the same).

On the 2-core AMD EPYC, 2026-11-24, two runs: an update cost 6.9 and 8.1 ms inside the trainer,
4.2 and 5.9 ms alone. A hand-written probe of the same trainers, one config per process,
measured 4.2-4.4 ms inside. So an update costs about the same inside the trainer as alone, and
at ratio 4 the 32 updates of an iteration take longer than its 2,048 env steps. This script's
trainers run slower than the probe's (207 against 112 ms per iteration of collection), which
is not explained.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time


def per_call(fn, *args, repeats: int) -> float:
  import jax
  jax.block_until_ready(fn(*args))
  start = time.perf_counter()
  for _ in range(repeats):
    out = fn(*args)
  jax.block_until_ready(out)
  return (time.perf_counter() - start) / repeats


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--env", default="Hopper")
  p.add_argument("--chunks", type=int, default=3, help="timed chunks of 10 iterations")
  args = p.parse_args()
  os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + (
      " --xla_force_host_platform_device_count=1")
  import jax

  import mjx_hopper
  from mjx_hopper import loop, presets, replay
  mjx_hopper.use_compile_cache()
  base = presets.get(args.env, "cpu").train
  iteration_s, updates = {}, {}
  for name, changes in [("collect only", dict(min_replay=base.replay_size)),
                        ("ratio 4", dict(replay_ratio=4.0)), ("ratio 8", dict(replay_ratio=8.0))]:
    cfg = presets.run_config(args.env, "cpu", train=dataclasses.replace(
        base, iterations_per_chunk=10, min_replay=changes.pop("min_replay", 20_480), **changes))
    trainer = loop.build(cfg)
    state = loop.init(cfg, trainer, cfg.members())
    for _ in range(3):  # past min_replay, so that the timed chunks learn
      state, _ = trainer.train_chunk(state)
    start = time.perf_counter()
    for _ in range(args.chunks):
      state, metrics = trainer.train_chunk(state)
    jax.block_until_ready(metrics)
    iteration_s[name] = (time.perf_counter() - start) / (10 * args.chunks)
    updates[name] = cfg.train.updates_per_iteration
    agent_state = jax.tree.map(lambda x: x[0], state.agent)
    buffer, agent = jax.tree.map(lambda x: x[0], state.replay), trainer.agent
  hp = agent_state.hparams

  @jax.jit
  def eight_updates(agent_state, buffer, key):
    def one(s, k):
      batch = replay.sample(buffer, k, base.batch_size, hp["n_step"], hp["discount"],
                            window=agent.n_step)
      return agent.update(s, batch, k)
    return jax.lax.scan(one, agent_state, jax.random.split(key, 8))
  alone = per_call(eight_updates, agent_state, buffer, jax.random.PRNGKey(0), repeats=10) / 8
  inside = (iteration_s["ratio 8"] - iteration_s["ratio 4"]) / (updates["ratio 8"] -
                                                                   updates["ratio 4"])
  print(f"{args.env}, D4PG cpu preset, batch {base.batch_size}, {jax.devices()[0].device_kind}")
  print("| trainer | ms per iteration | env steps/s |")
  print("|---|---|---|")
  for name, s in iteration_s.items():
    print(f"| {name} | {s * 1000:.0f} | {base.steps_per_iteration / s:,.0f} |")
  print(f"\nupdate inside the trainer: {inside * 1000:.1f} ms; alone (scan of 8): "
        f"{alone * 1000:.1f} ms")


if __name__ == "__main__":
  main()
