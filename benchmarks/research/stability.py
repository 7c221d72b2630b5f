"""Stability under random actions: N envs stepped T times with uniform random actions and
auto-reset, counting steps whose physics state is not finite and the largest joint speed.

    python benchmarks/research/stability.py --env Humanoid --num-envs 256 --steps 10000
    python benchmarks/research/stability.py --env Humanoid --num-envs 4096 --dump runs/nonfinite.npz

With --dump, the state each non-finite step started from (the first such step of each chunk)
is saved, so that `replay_nonfinite.py` (in this folder) can step it again and say where it
failed.
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from mjx_hopper import envs, parallel

# What mjx.step reads of a state, besides the model: enough to redo a step exactly.
SNAPSHOT = ("qpos", "qvel", "qacc_warmstart", "time")


def make_run(env, num_envs: int, chunk: int):
  """A compiled call advancing the batch `chunk` steps. It returns the counts of non-finite
  states and ended episodes, the largest finite |qvel|, and the first non-finite step's
  starting state and action (`found` says whether there was one)."""

  def one_step(carry, xs):
    state, caught = carry
    key, t = xs
    act_key, reset_key = jax.random.split(key)
    action = jax.random.uniform(act_key, (num_envs, env.action_size), minval=-1, maxval=1)
    stepped = jax.vmap(env.step)(state, action)
    qvel = stepped.pipeline_state.qvel
    bad = ~jnp.isfinite(qvel).all(axis=1) | ~jnp.isfinite(stepped.pipeline_state.qpos).all(axis=1)
    e = jnp.argmax(bad)
    take = bad.any() & ~caught["found"]
    now = {k: getattr(state.pipeline_state, k)[e] for k in SNAPSHOT}
    now.update(ctrl=action[e], step=t, env=e, found=take)
    caught = jax.tree.map(lambda n, c: jnp.where(take, n, c), now, caught)
    fresh = jax.vmap(env.reset)(jax.random.split(reset_key, num_envs))
    done = stepped.done > 0
    state = jax.tree.map(
        lambda f, s: jnp.where(done.reshape(done.shape + (1,) * (s.ndim - 1)), f, s),
        fresh, stepped)
    return (state, caught), (bad.sum(), jnp.where(jnp.isfinite(qvel), jnp.abs(qvel), 0).max(),
                             done.sum())

  def run(state, key):
    data = env._data0
    caught = {k: jnp.zeros_like(getattr(data, k)) for k in SNAPSHOT}
    caught.update(ctrl=jnp.zeros(env.action_size), step=jnp.zeros((), jnp.int32),
                  env=jnp.zeros((), jnp.int32), found=jnp.zeros((), bool))
    (state, caught), (bad, top, done) = jax.lax.scan(
        one_step, (state, caught), (jax.random.split(key, chunk), jnp.arange(chunk)))
    return state, bad.sum(), top.max(), done.sum(), caught

  return jax.jit(run)


def check(env, num_envs: int, steps: int, chunk: int, log=None, seed: int = 0,
          max_seconds: float | None = None) -> dict:
  """Steps `num_envs` envs `steps` random-action steps (in whole chunks), or fewer if
  `max_seconds` is spent first (then "steps" says how many ran): the counts of
  non-finite states and ended episodes, the largest |qvel|, the steps run, the seconds, and
  `caught`: for each chunk with a non-finite state, the state and action its first one
  started from (arrays of SNAPSHOT's fields, "ctrl", and "step" counted from the start).
  `log`, if given, is called with the running counts after each chunk. `seed` picks the resets
  and actions."""
  key = jax.random.PRNGKey(seed)
  state = parallel.shard(jax.vmap(env.reset)(jax.random.split(key, num_envs)))
  run = make_run(env, num_envs, chunk)
  bad = episodes = 0
  top = 0.0
  caught = []
  t0 = time.perf_counter()
  done_steps = 0
  for i in range(steps // chunk):
    if max_seconds is not None and time.perf_counter() - t0 > max_seconds:
      break
    state, b, t, d, c = run(state, jax.random.fold_in(key, i))
    done_steps += chunk
    bad, top, episodes = bad + int(b), max(top, float(t)), episodes + int(d)
    if bool(c["found"]):
      c = jax.tree.map(np.asarray, c)
      c["step"] = i * chunk + int(c["step"])
      caught.append(c)
    if log:
      log(f"{(i + 1) * chunk} steps: {bad} non-finite, largest |qvel| {top:.1f}")
  return {"bad": bad, "top": top, "episodes": episodes, "steps": done_steps,
          "seconds": time.perf_counter() - t0, "caught": caught}


def dump(path: str, caught: list[dict]) -> None:
  """Writes caught non-finite steps to an .npz: one array per field, stacked over events."""
  np.savez(path, **{k: np.stack([c[k] for c in caught]) for k in caught[0]})


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--env", default="Humanoid")
  parser.add_argument("--num-envs", type=int, default=256)
  parser.add_argument("--steps", type=int, default=10_000)
  parser.add_argument("--chunk", type=int, default=500)
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--max-seconds", type=float, help="stop after the chunk that passes this")
  parser.add_argument("--dump", help="save the non-finite steps' starting states to this .npz")
  args = parser.parse_args()
  r = check(envs.make(args.env), args.num_envs, args.steps, args.chunk, seed=args.seed,
            max_seconds=args.max_seconds)
  print(f"{args.env}: {args.num_envs} envs x {r['steps']} random-action steps "
        f"({args.num_envs * r['steps']:,} env steps, {r['episodes']:,} episodes ended) on "
        f"{jax.devices()[0].platform} in {r['seconds']:.0f} s: "
        f"{r['bad']} non-finite states, largest |qvel| {r['top']:.1f}")
  if args.dump and r["caught"]:
    dump(args.dump, r["caught"])
    print(f"{len(r['caught'])} non-finite steps' starting states saved to {args.dump}")


if __name__ == "__main__":
  main()
