"""Env throughput: MJX env steps/s by batch size and device count, with compile time, against
MuJoCo C (`mujoco.rollout`, same MJCF) and PyBullet's own env, measured in one run.

    python benchmarks/env_throughput.py                      # CPU: 1 and 2 devices
    python benchmarks/env_throughput.py --batches 1,1024,32768 --devices 1   # on a GPU

Each MJX row steps N auto-resetting envs with random actions, T steps per compiled call; the
rate is the median of 3 timed calls after a warm-up. MuJoCo C rolls out the same model with
random controls from reset states (4 physics steps = 1 env step, no observation or reward).
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


def time_stepper(env, num_envs: int, steps: int) -> dict:
  """Traces (`lower`) and compiles a stepper of `num_envs` envs and `steps` steps per call, then
  times it: the median of 3 calls after a warm-up."""
  import jax

  from mjx_hopper import rollout

  init, run = rollout.make_stepper(env, num_envs, steps)
  key = jax.random.PRNGKey(0)
  state = init(key)
  start = time.perf_counter()
  lowered = run.lower(state, key)
  traced = time.perf_counter()
  compiled = lowered.compile()
  trace_s, compile_s = traced - start, time.perf_counter() - traced
  state, r = compiled(state, key)
  r.block_until_ready()
  times = []
  for i in range(3):
    t0 = time.perf_counter()
    state, r = compiled(state, jax.random.fold_in(key, i))
    r.block_until_ready()
    times.append(time.perf_counter() - t0)
  return {"trace_s": trace_s, "compile_s": compile_s,
          "env_steps_per_s": num_envs * steps / statistics.median(times)}


def mjx_rows(env_id: str, batches: list[int], steps_total: int) -> list[dict]:
  import jax

  from mjx_hopper import envs

  env = envs.make(env_id)
  devices = jax.devices()
  rows = []
  for n in batches:
    timed = time_stepper(env, n, max(20, min(1000, steps_total // n)))
    compile_s = timed["trace_s"] + timed["compile_s"]
    rows.append({"engine": "MJX", "platform": devices[0].platform, "devices": len(devices),
                 "batch": n, "compile_s": compile_s, "env_steps_per_s": timed["env_steps_per_s"]})
    print(f"  MJX {devices[0].platform} x{len(devices)} batch {n:>6}: "
          f"{rows[-1]['env_steps_per_s']:>12,.0f} env steps/s, compile {compile_s:.1f} s",
          file=sys.stderr, flush=True)
  return rows


def mujoco_c_row(env_id: str, threads: int, batch: int = 256, physics_steps: int = 1000) -> dict:
  import mujoco
  import numpy as np
  from mujoco import rollout as mj_rollout

  from mjx_hopper import envs

  env = envs.make(env_id)
  model = env.mj_model
  rng = np.random.default_rng(0)
  data = mujoco.MjData(model)
  spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
  states = []
  for _ in range(batch):
    mujoco.mj_resetData(model, data)
    data.qpos[env._qadr] = rng.uniform(-env.reset_noise, env.reset_noise, env.action_size)
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
    from mjx_hopper.envs import pybullet_oracle
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
      with pybullet_oracle._quiet():
        env.reset()
  return {"engine": "PyBullet", "platform": "cpu", "devices": 1, "batch": 1, "compile_s": 0.0,
          "env_steps_per_s": steps / (time.perf_counter() - t0)}


def table(rows: list[dict]) -> str:
  """Markdown, with each row's rate against PyBullet's and MuJoCo C's on the same robot."""
  def reference(env_id, engine):
    return next((r["env_steps_per_s"] for r in rows
                 if r["env"] == env_id and r["engine"].startswith(engine)), None)

  lines = ["| env | engine | platform | devices | batch | compile (s) | env steps/s "
           "| × PyBullet | ÷ MuJoCo C |", "|---|---|---|---|---|---|---|---|---|"]
  for r in rows:
    bullet, c = reference(r["env"], "PyBullet"), reference(r["env"], "MuJoCo C")
    ratio_b = f"{r['env_steps_per_s'] / bullet:.1f}" if bullet else "-"
    ratio_c = f"{r['env_steps_per_s'] / c:.2f}" if c else "-"
    lines.append(f"| {r['env']} | {r['engine']} | {r['platform']} | {r['devices']} "
                 f"| {r['batch']} | {r['compile_s']:.1f} | {r['env_steps_per_s']:,.0f} "
                 f"| {ratio_b} | {ratio_c} |")
  return "\n".join(lines)


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--envs", default="Hopper")
  parser.add_argument("--batches", default="1,64,256,1024,4096")
  parser.add_argument("--devices", default="1,2",
                      help="XLA CPU device counts to run MJX on (on a GPU: GPUs used)")
  parser.add_argument("--steps-total", type=int, default=200_000,
                      help="env steps per timed call, roughly (T = this / batch)")
  parser.add_argument("--json", help="also write the rows to this file")
  parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
  args = parser.parse_args()
  env_ids = args.envs.split(",")
  batches = [int(b) for b in args.batches.split(",")]

  if args.worker:  # one device count, in its own process: XLA reads the flag at start-up
    print(json.dumps([dict(r, env=e) for e in env_ids
                      for r in mjx_rows(e, batches, args.steps_total)]))
    return

  # This process measures the CPU references only; it must leave the accelerator to the workers.
  worker_env = dict(os.environ)
  os.environ["JAX_PLATFORMS"] = "cpu"
  rows = []
  for e in env_ids:
    row = pybullet_row(e)
    rows += [dict(row, env=e)] if row else []
    rows.append(dict(mujoco_c_row(e, threads=2), env=e))
  for d in [int(x) for x in args.devices.split(",")]:
    env = dict(worker_env, XLA_FLAGS=f"--xla_force_host_platform_device_count={d}",
               CUDA_VISIBLE_DEVICES=worker_env.get("CUDA_VISIBLE_DEVICES",
                                                   ",".join(map(str, range(d)))))
    out = subprocess.run([sys.executable, __file__, "--worker", "--envs", args.envs,
                          "--batches", args.batches, "--steps-total", str(args.steps_total)],
                         env=env, stdout=subprocess.PIPE, text=True)
    if out.returncode:
      raise SystemExit(f"the MJX worker on {d} device(s) failed (exit {out.returncode})")
    rows += json.loads(out.stdout.strip().splitlines()[-1])
  rows.sort(key=lambda r: (env_ids.index(r["env"]), r["engine"] != "PyBullet",
                           not r["engine"].startswith("MuJoCo"), r["devices"], r["batch"]))
  print(f"# env throughput, {time.strftime('%Y-%m-%d')}, {platform.node()}, "
        f"{os.cpu_count()} CPUs\n")
  print(table(rows))
  if args.json:
    with open(args.json, "w") as f:
      json.dump(rows, f, indent=1)


if __name__ == "__main__":
  main()
