"""Stepping S members' envs: nested under a member vmap, or as one flat batch.

    python benchmarks/research/member_step_layout.py --members 1,16 --envs 512   # on a GPU

A sweep's trainer holds S members x n envs per device. Under its member vmap the physics is a
nested batch, vmap(vmap(step)) over (S, n); the alternative reshapes the envs to one batch of
S*n and steps them with one vmap. This times both, the env step alone with random actions, T
steps per compiled call (the median of 3 calls after a warm-up), in one process on the default
device. On one H100 (2026-11-24) flat ran 1.04x, 1.19x and 0.94x nested at 1, 4 and 16 members
of 512 envs, so the trainer keeps the nested vmap.
"""

from __future__ import annotations

import argparse
import statistics
import time


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  p.add_argument("--env", default="Hopper")
  p.add_argument("--members", default="1,4,16", help="comma-separated S")
  p.add_argument("--envs", type=int, default=512, help="envs per member")
  p.add_argument("--steps", type=int, default=40, help="env steps per compiled call")
  args = p.parse_args()
  import jax

  from mjx_hopper import envs

  env = envs.AutoReset(envs.make(args.env))
  step = jax.vmap(env.step)

  def nested(state, action):
    return jax.vmap(step)(state, action)

  def flat(state, action):
    shape = action.shape[:2]
    flat_in = jax.tree.map(lambda x: x.reshape((x.shape[0] * x.shape[1],) + x.shape[2:]),
                           (state, action))
    return jax.tree.map(lambda x: x.reshape(shape + x.shape[1:]), step(*flat_in))

  def stepper(layout):
    def run(state, key):
      def one(state, k):
        action = jax.random.uniform(k, state.obs.shape[:2] + (env.action_size,), minval=-1,
                                    maxval=1)
        state = layout(state, action)
        return state, state.reward.sum()
      state, rewards = jax.lax.scan(one, state, jax.random.split(key, args.steps))
      return state, rewards.sum()
    return jax.jit(run, donate_argnums=0)

  print(f"{args.env}, {args.envs} envs per member, {args.steps} steps per call, "
        f"{jax.devices()[0].device_kind}")
  print("| members | layout | compile s | env steps/s | flat / nested |")
  print("|---|---|---|---|---|")
  for members in (int(m) for m in args.members.split(",")):
    keys = jax.random.split(jax.random.PRNGKey(0), members * args.envs)
    rates = {}
    for name, layout in (("nested", nested), ("flat", flat)):
      state = jax.vmap(env.reset)(keys)
      state = jax.tree.map(lambda x: x.reshape((members, args.envs) + x.shape[1:]), state)
      run = stepper(layout)
      start = time.perf_counter()
      compiled = run.lower(state, jax.random.PRNGKey(1)).compile()
      compile_s = time.perf_counter() - start
      state, r = compiled(state, jax.random.PRNGKey(1))
      r.block_until_ready()
      times = []
      for i in range(3):
        t0 = time.perf_counter()
        state, r = compiled(state, jax.random.PRNGKey(2 + i))
        r.block_until_ready()
        times.append(time.perf_counter() - t0)
      rates[name] = members * args.envs * args.steps / statistics.median(times)
      ratio = f"{rates['flat'] / rates['nested']:.2f}" if name == "flat" else ""
      print(f"| {members} | {name} | {compile_s:.1f} | {rates[name]:,.0f} | {ratio} |",
            flush=True)


if __name__ == "__main__":
  main()
