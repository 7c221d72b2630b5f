"""The Gymnasium door's cost: env steps/s of `envs.to_gymnasium(env, num_envs=N)` stepped from
Python with NumPy random actions (a step per call, its outputs copied to NumPy), against the JAX
env stepped inside one compiled scan (`rollout.make_stepper`), in the same process and on the
same devices. The single Gymnasium env is timed too.

    python benchmarks/gymnasium_throughput.py            # Hopper, 256 envs, every CPU core
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import common

ENGINES = {"jax": "JAX env, compiled scan (rollout.make_stepper)",
           "vector": "Gymnasium VectorEnv (envs.to_gymnasium)",
           "single": "Gymnasium Env (envs.to_gymnasium)"}


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--env", default="Hopper")
  p.add_argument("--num-envs", type=int, default=256)
  p.add_argument("--steps", type=int, default=200, help="steps of every env per timing")
  p.add_argument("--repeats", type=int, default=5, help="timings; the median is reported")
  p.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1)
  p.add_argument("--name", default="gymnasium_throughput_cpu")
  args = p.parse_args()

  import mjx_hopper
  mjx_hopper.setup(cpu_devices=args.cpu_devices)
  import jax
  import numpy as np

  from mjx_hopper import envs
  from mjx_hopper.core import rollout

  env = envs.make(args.env)
  n, steps = args.num_envs, args.steps

  init, run = rollout.make_stepper(env, n, steps)
  key = jax.random.PRNGKey(0)
  timed = common.Timed(run, init(key), key)
  gyms = {"vector": (envs.to_gymnasium(env, num_envs=n), (n, env.action_size)),
          "single": (envs.to_gymnasium(env), (env.action_size,))}
  rng = np.random.default_rng(0)
  for gym_env, shape in gyms.values():
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
  seconds = {name: [] for name in ENGINES}
  for _ in range(args.repeats):
    seconds["jax"].append(timed())
    for name, (gym_env, shape) in gyms.items():
      seconds[name].append(gym_seconds(gym_env, shape))
  sizes = {"jax": n, "vector": n, "single": 1}
  rows = [{"engine": engine, "num_envs": sizes[name],
           "env_steps_per_s": sizes[name] * steps / statistics.median(seconds[name])}
          for name, engine in ENGINES.items()]
  jax_rate, vec_rate = rows[0]["env_steps_per_s"], rows[1]["env_steps_per_s"]
  print(common.table(["engine", "envs", "env steps/s"],
                     [[r["engine"], r["num_envs"], f"{r['env_steps_per_s']:,.0f}"] for r in rows]))
  print(f"VectorEnv / JAX env: {vec_rate / jax_rate:.2f}")
  devices = jax.local_devices()
  common.write_results(args.name, {
      "device": f"{devices[0].platform} x{len(devices)}",
      "versions": {"python": sys.version.split()[0], "jax": jax.__version__,
                   "gymnasium": __import__("gymnasium").__version__},
      "load_average_1min": os.getloadavg()[0], "env": args.env, "steps_per_timing": steps,
      "seconds": seconds, "rows": rows,
      "vector_env_over_jax_env": vec_rate / jax_rate})


if __name__ == "__main__":
  main()
