"""Where a sweep's collection spends its time on a GPU: the parts of the trainer's collect,
added one at a time, for S members x n envs.

    python benchmarks/research/sweep_collect_parts.py --members 1,16     # on a GPU

Each row is a compiled scan of iterations of `--unroll` env steps of every member's envs (one
flat batch; the trainer steps them nested under its member vmap, which member_step_layout.py
timed 6% faster at 16 members), then a write of those steps into each member's replay of
`--replay-size` transitions:
  physics   random actions, no replay write;
  + policy  the members' D4PG (gpu preset) exploring actions, under a member vmap;
  + insert  the trainer's write: replay.insert under the member vmap (a scatter, as each member
            has its own position);
  + insert, one position   the same write as one dynamic_update_slice at the position that
            every member shares (they step in lockstep).
Times are the median of 3 calls after a warm-up; env steps/s counts every member's.
"""

from __future__ import annotations

import argparse
import statistics
import time


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  p.add_argument("--env", default="Hopper")
  p.add_argument("--members", default="1,16", help="comma-separated S")
  p.add_argument("--envs", type=int, default=512, help="envs per member")
  p.add_argument("--unroll", type=int, default=4)
  p.add_argument("--iterations", type=int, default=10, help="per compiled call")
  p.add_argument("--replay-size", type=int, default=1_000_000, help="per member")
  args = p.parse_args()
  import jax
  import jax.numpy as jnp

  from mjx_hopper import agents, envs, replay, train

  env = envs.AutoReset(envs.make(args.env))
  agent = agents.make("d4pg", env.observation_size, env.action_size, agents.config("d4pg", "gpu"))
  rows = train.TrainConfig(num_envs=args.envs, unroll_length=args.unroll,
                           replay_size=args.replay_size).replay_rows()

  def flat_step(state, action):
    s, n = action.shape[:2]
    flat = jax.tree.map(lambda x: x.reshape((s * n,) + x.shape[2:]), (state, action))
    return jax.tree.map(lambda x: x.reshape((s, n) + x.shape[1:]), jax.vmap(env.step)(*flat))

  def insert_shared(buffer, steps):
    """steps (S, T, n, ...) written at the position every member shares."""
    pos = buffer.position[0]
    new = jax.tree.map(lambda b, x: jax.lax.dynamic_update_slice_in_dim(b, x, pos, axis=1),
                       buffer.steps, steps)
    t = args.unroll
    return replay.ReplayState(new, (buffer.position + t) % rows,
                              jnp.minimum(buffer.filled + t, rows))

  def make(policy: bool, insert):
    def iteration(carry, key):
      agent_state, env_state, buffer = carry

      def one(env_state, k):
        if policy:
          action = jax.vmap(agent.act)(agent_state, env_state.obs,
                                       jax.random.split(k, env_state.obs.shape[0]))
        else:
          action = jax.random.uniform(k, env_state.obs.shape[:2] + (env.action_size,),
                                      minval=-1, maxval=1)
        nxt = flat_step(env_state, action)
        step = replay.Step(obs=env_state.obs, action=action, reward=nxt.reward,
                           discount=1.0 - nxt.done, done=nxt.done,
                           next_obs=nxt.info["final_obs"])
        return nxt, step
      env_state, steps = jax.lax.scan(one, env_state, jax.random.split(key, args.unroll))
      steps = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), steps)   # (S, T, n, ...)
      if insert == "vmap":
        buffer = jax.vmap(replay.insert)(buffer, steps)
      elif insert == "shared":
        buffer = insert_shared(buffer, steps)
      return (agent_state, env_state, buffer), steps.reward.sum()

    def run(carry, key):
      carry, r = jax.lax.scan(iteration, carry, jax.random.split(key, args.iterations))
      return carry, r.sum()
    return jax.jit(run, donate_argnums=0)

  variants = [("physics", False, None), ("+ policy", True, None), ("+ insert", True, "vmap"),
              ("+ insert, one position", True, "shared")]
  print(f"{args.env}, {args.envs} envs per member, unroll {args.unroll}, replay "
        f"{args.replay_size:,} per member, {jax.devices()[0].device_kind}")
  print("| members | collect | compile s | ms per iteration | env steps/s |")
  print("|---|---|---|---|---|")
  for members in (int(m) for m in args.members.split(",")):
    for name, policy, insert in variants:
      keys = jax.random.split(jax.random.PRNGKey(0), members)
      agent_state = jax.vmap(agent.init)(keys)
      env_state = jax.vmap(jax.vmap(env.reset))(
          jax.vmap(lambda k: jax.random.split(k, args.envs))(keys))
      buffer = jax.vmap(lambda _: replay.init(rows, args.envs, env.observation_size,
                                              env.action_size))(keys)
      # Own buffers for every leaf (the agent's target networks start as its networks' arrays),
      # as the call donates them.
      carry = jax.tree.map(jnp.array, (agent_state, env_state, buffer))
      run = make(policy, insert)
      start = time.perf_counter()
      compiled = run.lower(carry, keys[0]).compile()
      compile_s = time.perf_counter() - start
      carry, r = compiled(carry, keys[0])
      r.block_until_ready()
      times = []
      for i in range(3):
        t0 = time.perf_counter()
        carry, r = compiled(carry, jax.random.PRNGKey(i))
        r.block_until_ready()
        times.append(time.perf_counter() - t0)
      per_iteration = statistics.median(times) / args.iterations
      rate = members * args.envs * args.unroll / per_iteration
      print(f"| {members} | {name} | {compile_s:.1f} | {1000 * per_iteration:.2f} | {rate:,.0f} |",
            flush=True)
      del carry


if __name__ == "__main__":
  main()
