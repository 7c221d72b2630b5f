"""Steps again the states that `stability.py --dump` saved (the start of a control step that
ended non-finite) and says where each went wrong: in which physics substep, which stage of MJX's
step first made a non-finite value, and what MuJoCo C (float64) makes of the same step.

    python benchmarks/research/replay_nonfinite.py runs/nonfinite.npz --env Humanoid
    python benchmarks/research/replay_nonfinite.py runs/h_shipped_seed2.npz --variant shipped

--variant rebuilds a Humanoid variant of `humanoid_options.py`. On the CPU an event recorded on
a GPU need not repeat: the float32 arithmetic differs, so the report says whether it did.
"""

from __future__ import annotations

import argparse
import os
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import forward, solver

from mjx_hopper import envs


def nonfinite(tree) -> list[str]:
  """Paths of the leaves of `tree` holding a non-finite float."""
  out = []
  for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
    leaf = np.asarray(leaf)
    if leaf.dtype.kind == "f" and not np.isfinite(leaf).all():
      out.append(jax.tree_util.keystr(path))
  return out


def stages(m):
  """MJX's step, split where a non-finite value could first appear."""
  return [("position (kinematics, mass matrix, collision, constraints)",
           lambda d: forward.fwd_position(m, d)),
          ("velocity (bias forces)", lambda d: forward.fwd_velocity(m, d)),
          ("actuation", lambda d: forward.fwd_actuation(m, d)),
          ("smooth acceleration", lambda d: forward.fwd_acceleration(m, d)),
          ("constraint solver", lambda d: solver.solve(m, d)),
          ("integration", lambda d: forward.euler(m, d))]


def replay_mjx(env, event: dict) -> str:
  m = env.mjx_model
  d = mjx.make_data(m).replace(ctrl=jnp.asarray(event["ctrl"]),
                               **{k: jnp.asarray(event[k]) for k in ("qpos", "qvel",
                                                                     "qacc_warmstart", "time")})
  jit_stages = [(name, jax.jit(f)) for name, f in stages(m)]
  for sub in range(env.n_substeps):
    for name, f in jit_stages:
      before, d = d, f(d)
      bad = nonfinite(d)
      if bad:
        return (f"substep {sub + 1} of {env.n_substeps}, stage '{name}': non-finite "
                f"{', '.join(bad[:6])}{' ...' if len(bad) > 6 else ''} (|qvel| max "
                f"{np.abs(np.asarray(before.qvel)).max():.1f} before it)")
  return (f"finite after {env.n_substeps} substeps (max |qvel| "
          f"{np.abs(np.asarray(d.qvel)).max():.1f})")


def replay_c(env, event: dict) -> str:
  model = env.mj_model
  data = mujoco.MjData(model)
  data.qpos[:], data.qvel[:] = event["qpos"], event["qvel"]
  data.qacc_warmstart[:], data.ctrl[:] = event["qacc_warmstart"], event["ctrl"]
  data.time = event["time"]
  top = 0.0
  for sub in range(env.n_substeps):
    mujoco.mj_step(model, data)
    if data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number:
      return f"unstable in substep {sub + 1} (MuJoCo's bad-qacc warning)"
    top = max(top, np.abs(data.qvel).max())
  return (f"finite, max |qvel| {top:.1f}, {data.ncon} contacts, solver iterations "
          f"{int(data.solver_niter[0])}")


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("npz")
  parser.add_argument("--env", default="Humanoid")
  parser.add_argument("--variant", help="a humanoid_options.py variant, instead of --env")
  args = parser.parse_args()
  if args.variant:
    sys.path.insert(0, os.path.dirname(__file__))
    import humanoid_options
    env = humanoid_options.variant(args.variant)
  else:
    env = envs.make(args.env)
  events = dict(np.load(args.npz))
  for i in range(len(events["step"])):
    event = {k: v[i] for k, v in events.items()}
    print(f"event {i}: step {int(event['step'])}, env {int(event['env'])}, start |qvel| max "
          f"{np.abs(event['qvel']).max():.1f}, torso z {event['qpos'][2]:.3f}")
    print(f"  MJX float32 ({jax.devices()[0].platform}): {replay_mjx(env, event)}")
    print(f"  MuJoCo C float64: {replay_c(env, event)}")


if __name__ == "__main__":
  main()
