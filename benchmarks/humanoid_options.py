"""What Humanoid's MJX step costs on this machine, under model options that might make it cheaper:
floor contacts for fewer geoms, and fewer solver iterations. Each variant changes the MuJoCo
model before `mjx.put_model` and is timed like `env_throughput.py` (N auto-resetting envs with
random actions, over every XLA device), with the count of non-finite states seen.

    XLA_FLAGS=--xla_force_host_platform_device_count=2 python benchmarks/humanoid_options.py
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from mjx_hopper import envs, rollout

LEGS = ("right_thigh1", "right_shin1", "right_foot", "left_thigh1", "left_shin1", "left_foot")


def variant(name: str):
  """A Humanoid whose model is changed as `name` says."""
  env = envs.make("Humanoid")
  model = env.mj_model
  if "legs" in name:  # only the legs can touch the floor
    for g in range(model.ngeom):
      if model.geom(g).name not in LEGS and model.geom(g).name != "floor":
        model.geom_contype[g] = model.geom_conaffinity[g] = 0
  if "2/6" in name:
    model.opt.iterations, model.opt.ls_iterations = 2, 6
  if "1/4" in name:
    model.opt.iterations, model.opt.ls_iterations = 1, 4
  env.mjx_model = mjx.put_model(model)
  env._data0 = mjx.make_data(env.mjx_model)
  return env


def measure(env, num_envs: int, steps: int) -> tuple[float, int]:
  init, run = rollout.make_stepper(env, num_envs, steps)
  key = jax.random.PRNGKey(0)
  state = init(key)
  compiled = run.lower(state, key).compile()
  state, _ = compiled(state, key)
  times, bad = [], 0
  for i in range(3):
    t0 = time.perf_counter()
    state, r = compiled(state, jax.random.fold_in(key, i))
    r.block_until_ready()
    times.append(time.perf_counter() - t0)
    bad += int(jnp.sum(~jnp.isfinite(state.pipeline_state.qvel).all(-1)))
  return num_envs * steps / statistics.median(times), bad


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--num-envs", type=int, default=64)
  parser.add_argument("--steps", type=int, default=200)
  parser.add_argument("--variants", default="4/8,legs 4/8,2/6,legs 2/6")
  args = parser.parse_args()
  print(f"| Humanoid variant | contacts | env steps/s ({len(jax.devices())} devices, "
        f"{args.num_envs} envs) | non-finite states at the timed calls' ends |")
  print("|---|---|---|---|")
  for name in args.variants.split(","):
    env = variant(name)
    rate, bad = measure(env, args.num_envs, args.steps)
    contacts = mjx.make_data(env.mjx_model).contact.dist.shape[0]
    print(f"| {name} | {contacts} | {rate:,.0f} | {bad} |", flush=True)


if __name__ == "__main__":
  main()
