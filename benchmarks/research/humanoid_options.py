"""What Humanoid's MJX step costs on this machine, under model options that might make it cheaper:
floor contacts for fewer geoms, fewer solver iterations, fewer and longer physics substeps per
0.0165 s control step. Each variant changes the MuJoCo model before `mjx.put_model` and is timed
like `benchmarks/env_throughput.py` (N auto-resetting envs with random actions, over every XLA
device), with the count of non-finite states seen; with --stability it is instead run through
`stability.py`'s check (N envs x T random-action steps, non-finite states and largest |qvel|),
and with --accuracy its solver is compared with a converged one: on states of its own
random-action episodes, the relative error of MJX's accelerations (`qacc`, float32, warm-started
as in the env) against MuJoCo C's in float64 with 100 iterations and tolerance 1e-12.

A variant is words separated by spaces, each a change from the shipped model: "all" (every part
touches the floor), "legs" (only the legs do), "I/L" (I solver iterations, L line-search steps),
"dtK" (K substeps of 0.0165 / K s instead of 4), "limref=A,B" (every joint limit's solref),
"limimp=D0,D1" (the first two numbers of every joint limit's solimp), "arm=A" (armature A on
every hinge), "tol=T" (the solver's tolerance); "shipped" changes nothing. --variants separates
variants with ";", or with "," when it has neither ";" nor "=" (whose values hold commas).

    XLA_FLAGS=--xla_force_host_platform_device_count=2 \
        python benchmarks/research/humanoid_options.py
    python benchmarks/research/humanoid_options.py --stability 10000 --num-envs 256 \
        --variants "shipped"
    python benchmarks/research/humanoid_options.py --accuracy 2000 --variants "shipped;3/3;2/4"
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from mjx_hopper import envs, rollout

LEGS = ("right_thigh", "right_shin", "right_foot", "left_thigh", "left_shin", "left_foot")


def edit(model, word: str, name: str) -> None:
  """Apply one variant word's change to the MuJoCo model."""
  key, _, value = word.partition("=")
  if key in ("limref", "limimp"):
    values = [float(v) for v in value.split(",")]
    target = model.jnt_solref if key == "limref" else model.jnt_solimp
    target[:, :len(values)] = values
  elif key == "tol":
    model.opt.tolerance = float(value)
  elif key == "arm":
    model.dof_armature[6:] = float(value)  # the hinges; the free joint's 6 dofs keep none
  elif "/" in word:
    model.opt.iterations, model.opt.ls_iterations = map(int, word.split("/"))
  elif word.startswith("dt"):
    model.opt.timestep = envs.Humanoid.control_dt / int(word[2:])
  elif word not in ("shipped", "all", "legs"):
    raise SystemExit(f"unknown variant word {word!r} in {name!r}: use shipped, all, legs, "
                     "I/L, dtK, arm=A, tol=T, limref=A,B or limimp=D0,D1")


def variant(name: str):
  """A Humanoid changed from the shipped one as `name` says."""
  words = name.split()
  attributes = {"edit_model": lambda self, model: [edit(model, w, name) for w in words]}
  for word in words:
    if word in ("all", "legs"):
      attributes["floor_bodies"] = LEGS if word == "legs" else None
    elif word.startswith("dt"):
      attributes["n_substeps"] = int(word[2:])
  return type("HumanoidVariant", (envs.Humanoid,), attributes)()


def variant_names(text: str) -> list[str]:
  """The variants of a --variants value (the module's docstring says how they are separated)."""
  return text.split(";" if ";" in text or "=" in text else ",")


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


def stability(args) -> None:
  sys.path.insert(0, os.path.dirname(__file__))
  import stability as check
  print("| Humanoid variant | seed | envs x steps | non-finite states | largest abs(qvel) | s |")
  print("|---|---|---|---|---|---|")
  for name in variant_names(args.variants):
    r = check.check(variant(name), args.num_envs, args.stability, min(500, args.stability),
                    seed=args.seed, max_seconds=args.max_seconds,
                    log=lambda line: print(f"  {name}: {line}", file=sys.stderr, flush=True))
    print(f"| {name} | {args.seed} | {args.num_envs} x {r['steps']} | {r['bad']} | "
          f"{r['top']:,.1f} | {r['seconds']:.0f} |", flush=True)
    if args.dump and r["caught"]:
      path = f"{args.dump}_{name.replace(' ', '_').replace('/', '-')}_seed{args.seed}.npz"
      check.dump(path, r["caught"])
      print(f"  {name}: {len(r['caught'])} non-finite steps' starting states saved to {path}",
            file=sys.stderr, flush=True)


# What the solve starts from: MJX's Data fields that `accuracy` copies into MuJoCo C's.
SOLVE_INPUTS = ("qpos", "qvel", "qacc_warmstart", "ctrl")


def episode_states(env, count: int, seed: int = 0) -> dict[str, np.ndarray]:
  """`count` states from random-action episodes (64 at a time, steps 1 to 15, alive envs only:
  most episodes end near step 20) with the action that follows each, as numpy arrays."""
  num_envs, steps = 64, 15
  reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
  out = {k: [] for k in SOLVE_INPUTS}
  key = jax.random.PRNGKey(seed)
  while len(out["qpos"]) * num_envs < count:
    key, reset_key = jax.random.split(key)
    state = reset(jax.random.split(reset_key, num_envs))
    for t in range(steps):
      key, act_key = jax.random.split(key)
      action = jax.random.uniform(act_key, (num_envs, env.action_size), minval=-1, maxval=1)
      if t:
        alive = np.asarray(state.done == 0)
        data = state.pipeline_state
        for k in SOLVE_INPUTS[:-1]:  # all but ctrl: the action that follows
          out[k].append(np.asarray(getattr(data, k))[alive])
        out["ctrl"].append(np.asarray(action)[alive])
      state = step(state, action)
  return {k: np.concatenate(v)[:count] for k, v in out.items()}


def accuracy(env, count: int) -> np.ndarray:
  """Relative error of the env's qacc against a converged float64 MuJoCo C solve, per state."""
  states = episode_states(env, count)
  forward = jax.jit(jax.vmap(lambda d: mjx.forward(env.mjx_model, d)))
  batch = jax.vmap(lambda q, v, w, c: env._data0.replace(qpos=q, qvel=v, qacc_warmstart=w,
                                                         ctrl=c))(
      *(jnp.asarray(states[k]) for k in SOLVE_INPUTS))
  ours = np.asarray(forward(batch).qacc, np.float64)
  model = env.mj_model.__copy__()
  model.opt.iterations, model.opt.ls_iterations, model.opt.tolerance = 100, 50, 1e-12
  data = mujoco.MjData(model)
  errors = np.empty(len(ours))
  for i in range(len(ours)):
    for k in SOLVE_INPUTS:
      getattr(data, k)[:] = states[k][i]
    mujoco.mj_forward(model, data)
    errors[i] = np.linalg.norm(ours[i] - data.qacc) / max(np.linalg.norm(data.qacc), 1.0)
  return errors


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--num-envs", type=int, default=64)
  parser.add_argument("--steps", type=int, default=200)
  parser.add_argument("--variants", default="shipped,all 4/8,legs,all")
  parser.add_argument("--stability", type=int, default=0, metavar="T",
                      help="run each variant T random-action steps through stability.py's check")
  parser.add_argument("--seed", type=int, default=0, help="the stability check's resets and actions")
  parser.add_argument("--max-seconds", type=float,
                      help="with --stability, stop each variant after the chunk that passes this")
  parser.add_argument("--dump", metavar="PREFIX",
                      help="with --stability, save each variant's non-finite steps' starting "
                      "states to PREFIX_VARIANT_seedS.npz (for replay_nonfinite.py)")
  parser.add_argument("--accuracy", type=int, default=0, metavar="S",
                      help="compare each variant's accelerations with a converged solve on S "
                      "states of its own random-action episodes")
  args = parser.parse_args()
  if args.stability:
    return stability(args)
  if args.accuracy:
    print("| Humanoid variant | states | qacc relative error: median | p90 | p99 | max |")
    print("|---|---|---|---|---|---|")
    for name in variant_names(args.variants):
      e = accuracy(variant(name), args.accuracy)
      print(f"| {name} | {len(e)} | " + " | ".join(
          f"{v:.1e}" for v in np.percentile(e, [50, 90, 99, 100])) + " |", flush=True)
    return
  print(f"| Humanoid variant | contacts | env steps/s ({len(jax.devices())} devices, "
        f"{args.num_envs} envs) | non-finite states at the timed calls' ends |")
  print("|---|---|---|---|")
  for name in variant_names(args.variants):
    env = variant(name)
    rate, bad = measure(env, args.num_envs, args.steps)
    contacts = mjx.make_data(env.mjx_model)._impl.contact.dist.shape[0]
    print(f"| {name} | {contacts} | {rate:,.0f} | {bad} |", flush=True)


if __name__ == "__main__":
  main()
