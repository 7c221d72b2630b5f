"""What Humanoid's MJX step costs on this machine, under model options that might make it cheaper:
floor contacts for fewer geoms, fewer solver iterations, fewer and longer physics substeps per
0.0165 s control step. Each variant changes the MuJoCo model before `mjx.put_model` and is timed
like `env_throughput.py` (N auto-resetting envs with random actions, over every XLA device),
with the count of non-finite states seen; with --stability it is instead run through
`stability.py`'s check (N envs x T random-action steps, non-finite states and largest |qvel|).

A variant is words separated by spaces, each a change from the shipped model: "all" (every part
touches the floor), "legs" (only the legs do), "I/L" (I solver iterations, L line-search steps),
"dtK" (K substeps of 0.0165 / K s instead of 4), "limref=A,B" (every joint limit's solref),
"limimp=D0,D1" (the first two numbers of every joint limit's solimp), "arm=A" (armature A on
every hinge), "tol=T" (the solver's tolerance); "shipped" changes nothing. --variants separates
variants with ";", or with "," when it has neither ";" nor "=" (whose values hold commas).

    XLA_FLAGS=--xla_force_host_platform_device_count=2 python benchmarks/humanoid_options.py
    python benchmarks/humanoid_options.py --stability 10000 --num-envs 256 --variants "shipped"
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
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
                      "states to PREFIX_VARIANT_seedS.npz (benchmarks/replay_nonfinite.py)")
  args = parser.parse_args()
  if args.stability:
    return stability(args)
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
