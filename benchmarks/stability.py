"""Stability under random actions: N envs stepped T times with uniform random actions and
auto-reset, counting steps whose physics state is not finite and the largest joint speed.

    python benchmarks/stability.py --env Humanoid --num-envs 256 --steps 10000
"""

import argparse
import time

import jax
import jax.numpy as jnp

from mjx_hopper import envs, parallel


def make_run(env, num_envs: int, chunk: int):
  """A compiled call advancing the batch `chunk` steps, returning per-chunk counts."""

  def one_step(state, key):
    act_key, reset_key = jax.random.split(key)
    action = jax.random.uniform(act_key, (num_envs, env.action_size), minval=-1, maxval=1)
    stepped = jax.vmap(env.step)(state, action)
    qvel = stepped.pipeline_state.qvel
    bad = ~jnp.isfinite(qvel).all(axis=1) | ~jnp.isfinite(stepped.pipeline_state.qpos).all(axis=1)
    fresh = jax.vmap(env.reset)(jax.random.split(reset_key, num_envs))
    done = stepped.done > 0
    state = jax.tree.map(
        lambda f, s: jnp.where(done.reshape(done.shape + (1,) * (s.ndim - 1)), f, s),
        fresh, stepped)
    return state, (bad.sum(), jnp.where(jnp.isfinite(qvel), jnp.abs(qvel), 0).max(), done.sum())

  def run(state, key):
    state, (bad, top, done) = jax.lax.scan(one_step, state, jax.random.split(key, chunk))
    return state, bad.sum(), top.max(), done.sum()

  return jax.jit(run)


def check(env, num_envs: int, steps: int, chunk: int, log=None, seed: int = 0) -> dict:
  """Steps `num_envs` envs `steps` random-action steps (in whole chunks): the counts of
  non-finite states and ended episodes, the largest |qvel|, the steps run and the seconds.
  `log`, if given, is called with the running counts after each chunk. `seed` picks the resets
  and actions."""
  key = jax.random.PRNGKey(seed)
  state = parallel.shard(jax.vmap(env.reset)(jax.random.split(key, num_envs)))
  run = make_run(env, num_envs, chunk)
  bad = episodes = 0
  top = 0.0
  t0 = time.perf_counter()
  for i in range(steps // chunk):
    state, b, t, d = run(state, jax.random.fold_in(key, i))
    bad, top, episodes = bad + int(b), max(top, float(t)), episodes + int(d)
    if log:
      log(f"{(i + 1) * chunk} steps: {bad} non-finite, largest |qvel| {top:.1f}")
  return {"bad": bad, "top": top, "episodes": episodes, "steps": steps // chunk * chunk,
          "seconds": time.perf_counter() - t0}


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--env", default="Humanoid")
  parser.add_argument("--num-envs", type=int, default=256)
  parser.add_argument("--steps", type=int, default=10_000)
  parser.add_argument("--chunk", type=int, default=500)
  parser.add_argument("--seed", type=int, default=0)
  args = parser.parse_args()
  r = check(envs.make(args.env), args.num_envs, args.steps, args.chunk, seed=args.seed)
  print(f"{args.env}: {args.num_envs} envs x {r['steps']} random-action steps "
        f"({args.num_envs * r['steps']:,} env steps, {r['episodes']:,} episodes ended) on "
        f"{jax.devices()[0].platform} in {r['seconds']:.0f} s: "
        f"{r['bad']} non-finite states, largest |qvel| {r['top']:.1f}")


if __name__ == "__main__":
  main()
