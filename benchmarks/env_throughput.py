"""Env throughput: MJX env steps/s by batch size and device count, with compile time, against
MuJoCo C (`mujoco.rollout`, same MJCF, physics only) and PyBullet's own env, in one run
(BENCHMARKS.md, "Env throughput": the method, and the commands for a GPU).

    python benchmarks/env_throughput.py                      # CPU: 1 and 2 devices
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import common


def mjx_rows(args) -> list[dict]:
  """Each of args.envs as N auto-resetting envs for each N of args.batches, random actions, T
  steps a call: the median of 3 after a warm-up, on this process's devices."""
  import jax

  from mjx_hopper import envs
  from mjx_hopper.core import rollout

  devices = jax.devices()
  rows = []
  for env_id in args.envs.split(","):
    env = envs.make(env_id)
    for n in map(int, args.batches.split(",")):
      steps = max(20, min(1000, args.steps_total // n))
      init, run = rollout.make_stepper(env, n, steps)
      key = jax.random.PRNGKey(0)
      timed = common.Timed(run, init(key), key)
      rate = n * steps / statistics.median(timed() for _ in range(3))
      compile_s = timed.trace_s + timed.compile_s
      rows.append({"engine": "MJX", "platform": devices[0].platform, "devices": len(devices),
                   "batch": n, "compile_s": compile_s, "env_steps_per_s": rate, "env": env_id})
      print(f"  MJX {devices[0].platform} x{len(devices)} batch {n:>6}: {rate:>12,.0f} env "
            f"steps/s, compile {compile_s:.1f} s", file=sys.stderr, flush=True)
  return rows


def mujoco_c_row(env_id: str, threads: int, batch: int = 256, physics_steps: int = 1000) -> dict:
  """Random controls from reset states, 4 physics steps to an env step."""
  import mujoco
  import numpy as np
  from mujoco import rollout as mj_rollout

  from mjx_hopper import envs

  env = envs.make(env_id)
  model = env.mj_model
  rng = np.random.default_rng(0)
  data = mujoco.MjData(model)
  spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
  joints = [model.jnt_qposadr[model.joint(name).id] for name in env.joints]
  states = []
  for _ in range(batch):
    mujoco.mj_resetData(model, data)
    data.qpos[joints] = rng.uniform(-env.reset_noise, env.reset_noise, env.action_size)
    states.append(np.empty(mujoco.mj_stateSize(model, spec)))
    mujoco.mj_getState(model, data, states[-1], spec)
  controls = rng.uniform(-1, 1, (batch, physics_steps, model.nu))
  datas = [mujoco.MjData(model) for _ in range(threads)]
  mj_rollout.rollout(model, datas, np.array(states), controls[:, :10])  # warm-up
  times = []
  for _ in range(3):
    t0 = time.perf_counter()
    mj_rollout.rollout(model, datas, np.array(states), controls)
    times.append(time.perf_counter() - t0)
  physics_rate = batch * physics_steps / statistics.median(times)
  return {"engine": f"MuJoCo C ({threads} threads)", "platform": "cpu", "devices": threads,
          "batch": batch, "compile_s": 0.0, "env_steps_per_s": physics_rate / env.n_substeps,
          "physics_steps_per_s": physics_rate}


def pybullet_row(env_id: str, seconds: float = 5.0) -> dict | None:
  try:
    pybullet_oracle = common.pybullet_oracle()
    env = pybullet_oracle.make(env_id)
  except ImportError:
    return None
  import numpy as np
  rng = np.random.default_rng(0)
  steps, t0 = 0, time.perf_counter()
  while time.perf_counter() - t0 < seconds:
    _, _, done, _ = env.step(rng.uniform(-1, 1, env.action_space.shape))
    steps += 1
    if done:
      with pybullet_oracle.quiet():
        env.reset()
  return {"engine": "PyBullet", "platform": "cpu", "devices": 1, "batch": 1, "compile_s": 0.0,
          "env_steps_per_s": steps / (time.perf_counter() - t0)}


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--envs", default="Hopper")
  p.add_argument("--batches", default="1,64,256,1024,4096")
  p.add_argument("--devices", default="1,2",
                 help="XLA CPU device counts to run MJX on (on a GPU: GPUs used)")
  p.add_argument("--steps-total", type=int, default=200_000,
                 help="env steps per timed call, roughly (T = this / batch)")
  p.add_argument("--label", default="cpu",
                 help="results: benchmarks/results/env_throughput_LABEL.json")
  args = common.parse(p, mjx_rows)  # a worker: one device count, as XLA reads it at start-up
  rows = []
  for d in map(int, args.devices.split(",")):
    result = common.worker(__file__, vars(args), d)
    if result is None:
      raise SystemExit(1)
    rows += result
  os.environ["JAX_PLATFORMS"] = "cpu"  # after the workers: this process measures the CPU alone
  for e in args.envs.split(","):
    for row in (pybullet_row(e), mujoco_c_row(e, threads=2)):
      if row:
        rows.append(dict(row, env=e))
        print(f"  {row['engine']} {e}: {row['env_steps_per_s']:,.0f} env steps/s",
              file=sys.stderr, flush=True)
  common.write_results(f"env_throughput_{args.label}", {"rows": rows})


if __name__ == "__main__":
  main()
