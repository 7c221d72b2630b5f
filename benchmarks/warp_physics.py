"""MJX's two physics implementations side by side on each robot's own model (issue 68): JAX, which
the envs use, and Warp (`mjx.put_model(m, impl="warp")`: MuJoCo Warp's kernels, on an NVIDIA
GPU, with warp-lang installed). For each robot and implementation: the first call's seconds
(trace, compile and one run of a scan of physics steps over a batch of worlds), then physics
steps/s (the median of 3 calls), and how far each lands from MuJoCo C, the reference engine,
after one step and after the scan, from the same starts (a random velocity and a constant
random control per world). Then the same distances with the constraint solver run to
convergence (`--converged-iterations`), which tells an unconverged solver's differences apart
from the growth of any small difference in a chaotic motion.

    bash benchmarks/gpu.sh "python benchmarks/warp_physics.py"

gpu.sh installs what .whl/ holds: add warp-lang's wheel there (mujoco-mjx carries MuJoCo Warp's
own code). It is larger than one call carries: send it in parts to the machine's /tmp in calls
that follow each other while it stays warm, join them into .whl/ there, then run gpu.sh.
"""

from __future__ import annotations

import statistics
import sys
import time

import common

IMPLS = ("jax", "warp")


def starts(m, worlds: int, seed: int = 0):
  """(qvel, ctrl), each (worlds, n): a random velocity and a constant control in range."""
  import numpy as np
  rng = np.random.default_rng(seed)
  low, high = m.actuator_ctrlrange.T
  return (rng.uniform(-0.5, 0.5, (worlds, m.nv)).astype(np.float32),
          rng.uniform(low, high, (worlds, m.nu)).astype(np.float32))


def reference(m, qvel, ctrl, steps: int):
  """MuJoCo C's qpos after 1 step and after `steps`, each (worlds, nq), in float64."""
  import mujoco
  import numpy as np
  out = np.zeros((2, len(qvel), m.nq))
  for w in range(len(qvel)):
    d = mujoco.MjData(m)
    d.qvel[:], d.ctrl[:] = qvel[w], ctrl[w]
    for step in range(steps):
      mujoco.mj_step(m, d)
      if step == 0:
        out[0, w] = d.qpos
    out[1, w] = d.qpos
  return out


def stepper(m, impl: str, steps: int, worlds: int):
  """(init(qvel, ctrl) -> batched data, run(data) -> (data, qpos after step 1)), jitted."""
  import jax
  from mujoco import mjx
  mx = mjx.put_model(m, impl=impl)
  sizes = {"naconmax": worlds * 64, "njmax": 512} if impl == "warp" else {}

  def one(qvel, ctrl):
    return mjx.make_data(m, impl=impl, **sizes).replace(qvel=qvel, ctrl=ctrl)

  def run(d):
    step = jax.vmap(mjx.step, in_axes=(None, 0))
    first = step(mx, d)
    last = jax.lax.fori_loop(1, steps, lambda _, x: step(mx, x), first)
    return last, first.qpos
  return jax.jit(jax.vmap(one)), jax.jit(run)


def measure(m, impl: str, args) -> dict:
  """The first call's seconds and physics steps/s over args.worlds worlds, and the distances to
  MuJoCo C over args.reference worlds."""
  import jax
  import numpy as np
  qvel, ctrl = starts(m, args.worlds)
  init, run = stepper(m, impl, args.steps, args.worlds)
  data = jax.block_until_ready(init(qvel, ctrl))
  t0 = time.perf_counter()
  jax.block_until_ready(run(data))
  first_call_s = time.perf_counter() - t0
  times = []
  for _ in range(3):
    t0 = time.perf_counter()
    jax.block_until_ready(run(data))
    times.append(time.perf_counter() - t0)
  row = {"first_call_s": first_call_s,
         "physics_steps_per_s": args.worlds * args.steps / statistics.median(times)}
  n = args.reference
  for label, m_ in (("", m), ("_converged", converged(m, args.converged_iterations))):
    want = reference(m_, qvel[:n], ctrl[:n], args.steps)
    init, run = stepper(m_, impl, args.steps, n)
    last, first = jax.device_get(run(init(qvel[:n], ctrl[:n])))
    row[f"qpos_gap_step1{label}"] = float(np.abs(first - want[0]).max())
    row[f"qpos_gap_last{label}"] = float(np.abs(last.qpos - want[1]).max())
    row[f"finite{label}"] = bool(np.isfinite(last.qpos).all())
  return row


def converged(m, iterations: int):
  """A copy of `m` whose constraint solver runs `iterations` iterations (and line-search
  iterations) at a tolerance of zero: as converged as float32 allows."""
  import copy
  m = copy.deepcopy(m)
  m.opt.iterations, m.opt.ls_iterations, m.opt.tolerance = iterations, iterations, 0.0
  return m


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--robots", default="Hopper,Walker2D,HalfCheetah,Ant,Humanoid")
  p.add_argument("--impls", default=",".join(IMPLS))
  p.add_argument("--worlds", type=int, default=4096, help="worlds stepped at once")
  p.add_argument("--steps", type=int, default=100, help="physics steps per call")
  p.add_argument("--reference", type=int, default=16, help="worlds checked against MuJoCo C")
  p.add_argument("--converged-iterations", type=int, default=100)
  p.add_argument("--label", default="")
  args = common.parse(p)

  import jax
  import mjx_hopper
  mjx_hopper.setup()
  from mjx_hopper import envs
  rows = []
  for robot in args.robots.split(","):
    m = envs.make(robot).mj_model
    for impl in args.impls.split(","):
      try:
        row = {"robot": robot, "impl": impl, **measure(m, impl, args)}
      except Exception as error:  # noqa: BLE001 - a robot Warp cannot step is a result too
        row = {"robot": robot, "impl": impl, "error": f"{type(error).__name__}: {error}"[:300]}
      rows.append(row)
      print(row, file=sys.stderr, flush=True)
  figures = {"device": jax.devices()[0].device_kind, "worlds": args.worlds, "steps": args.steps,
             "reference_worlds": args.reference,
             "converged_iterations": args.converged_iterations, "rows": rows}
  common.write_results("warp_physics" + (f"_{args.label}" if args.label else ""), figures)
  keys = ["robot", "impl", "first_call_s", "physics_steps_per_s", "qpos_gap_step1",
          "qpos_gap_last", "qpos_gap_step1_converged", "qpos_gap_last_converged"]
  print(common.table(keys, [[r.get(k, r.get("error", "")) if not isinstance(r.get(k), float)
                             else f"{r[k]:.3g}" for k in keys] for r in rows]))


if __name__ == "__main__":
  main()
