"""The Gymnasium door's cost: env steps/s of `envs.to_gymnasium(env, num_envs=N)` stepped from
Python with NumPy random actions (a step per call, its outputs copied to NumPy), against the JAX
env stepped inside one compiled scan (`rollout.make_stepper`), in the same process and on the
same devices. The single Gymnasium env is timed too.

    python benchmarks/gymnasium_throughput.py            # Hopper, 256 envs, every CPU core
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import common


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--env", default="Hopper")
  parser.add_argument("--num-envs", type=int, default=256)
  parser.add_argument("--steps", type=int, default=200, help="steps of every env per timing")
  parser.add_argument("--repeats", type=int, default=5, help="timings; the median is reported")
  parser.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1)
  parser.add_argument("--name", default="gymnasium_throughput_cpu")
  args = parser.parse_args()

  import mjx_hopper
  os.environ["XLA_FLAGS"] = mjx_hopper.xla_flags_with_cpu_devices(args.cpu_devices)
  import jax
  import numpy as np

  from mjx_hopper import envs, rollout

  mjx_hopper.use_compile_cache()
  env = envs.make(args.env)
  n, steps = args.num_envs, args.steps

  init, run = rollout.make_stepper(env, n, steps)
  key = jax.random.PRNGKey(0)
  timed = common.Timed(run, init(key), key)
  vec = envs.to_gymnasium(env, num_envs=n)
  single = envs.to_gymnasium(env)
  rng = np.random.default_rng(0)
  for gym_env, shape in ((vec, (n, env.action_size)), (single, (env.action_size,))):
    gym_env.reset(seed=0)
    gym_env.step(rng.uniform(-1, 1, shape).astype(np.float32))  # compiles

  def gym_seconds(gym_env, shape):
    """Seconds for `steps` steps; the single env is reset when its episode ends."""
    start = time.perf_counter()
    for _ in range(steps):
      _, _, terminated, truncated, _ = gym_env.step(rng.uniform(-1, 1, shape).astype(np.float32))
      if np.ndim(terminated) == 0 and (terminated or truncated):
        gym_env.reset()
    return time.perf_counter() - start

  # Taken in turns, so that a change in the machine's load falls on each.
  seconds = {"jax": [], "vector": [], "single": []}
  for _ in range(args.repeats):
    seconds["jax"].append(timed())
    seconds["vector"].append(gym_seconds(vec, (n, env.action_size)))
    seconds["single"].append(gym_seconds(single, (env.action_size,)))
  jax_rate, vec_rate, single_rate = (
      k * steps / statistics.median(seconds[name])
      for name, k in (("jax", n), ("vector", n), ("single", 1)))

  devices = jax.local_devices()
  rows = [{"engine": "JAX env, compiled scan (rollout.make_stepper)", "num_envs": n,
           "env_steps_per_s": jax_rate},
          {"engine": "Gymnasium VectorEnv (envs.to_gymnasium)", "num_envs": n,
           "env_steps_per_s": vec_rate},
          {"engine": "Gymnasium Env (envs.to_gymnasium)", "num_envs": 1,
           "env_steps_per_s": single_rate}]
  print(common.table(["engine", "envs", "env steps/s"],
                     [[r["engine"], r["num_envs"], f"{r['env_steps_per_s']:,.0f}"] for r in rows]))
  print(f"VectorEnv / JAX env: {vec_rate / jax_rate:.2f}")
  common.write_results(args.name, {
      "device": f"{devices[0].platform} x{len(devices)}",
      "versions": {"python": sys.version.split()[0], "jax": jax.__version__,
                   "gymnasium": __import__("gymnasium").__version__},
      "load_average_1min": os.getloadavg()[0], "env": args.env, "steps_per_timing": steps,
      "seconds": seconds, "rows": rows,
      "vector_env_over_jax_env": vec_rate / jax_rate})


if __name__ == "__main__":
  main()
