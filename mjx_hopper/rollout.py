"""Batched, jit-compiled rollouts of an env: whole episodes, and steady-state stepping."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from mjx_hopper import parallel
from mjx_hopper.envs import AutoReset, LocomotionEnv

Policy = Callable[[jax.Array, jax.Array], jax.Array]  # (obs (O,), key) -> action (A,)


def random_policy(obs: jax.Array, key: jax.Array, action_size: int) -> jax.Array:
  return jax.random.uniform(key, (action_size,), minval=-1.0, maxval=1.0)


def episodes(env: LocomotionEnv, policy: Policy, key: jax.Array, num_episodes: int,
             record_qpos: bool = False) -> dict[str, jax.Array]:
  """Runs `num_episodes` episodes in parallel, each to its end (at most env.episode_steps).

  Returns per-episode arrays of shape (num_episodes,): "length", "return", and the mean per
  step of each reward term, by name. With `record_qpos`, also "qpos" of the first episode,
  shape (episode_steps + 1, nq), frozen after its last step.
  """
  reset_keys, policy_key = jax.random.split(key)
  state = jax.vmap(env.reset)(jax.random.split(reset_keys, num_episodes))
  state = parallel.shard(state)

  def one_step(carry, step_key):
    state, running = carry
    keys = jax.random.split(step_key, num_episodes)
    action = jax.vmap(policy)(state.obs, keys)
    nxt = jax.vmap(env.step)(state, action)
    nxt = jax.tree.map(lambda new, old: _where_rows(running, new, old), nxt, state)
    out = {"reward": nxt.reward * running, "running": running,
           **{k: v * running for k, v in nxt.metrics.items()}}
    if record_qpos:
      out["qpos"] = nxt.pipeline_state.qpos[0]
    return (nxt, running & (nxt.done == 0)), out

  running = jnp.ones(num_episodes, bool)
  _, trace = jax.lax.scan(one_step, (state, running),
                          jax.random.split(policy_key, env.episode_steps))
  length = trace["running"].sum(0)
  result = {"length": length, "return": trace["reward"].sum(0)}
  for name in state.metrics:
    result[name] = trace[name].sum(0) / jnp.maximum(length, 1)
  if record_qpos:
    result["qpos"] = jnp.concatenate([state.pipeline_state.qpos[:1], trace["qpos"]])
  return result


def _where_rows(rows: jax.Array, new: jax.Array, old: jax.Array) -> jax.Array:
  return jnp.where(rows.reshape(rows.shape + (1,) * (new.ndim - 1)), new, old)


def make_stepper(env: LocomotionEnv, num_envs: int, steps: int):
  """A compiled function that advances `num_envs` auto-resetting envs by `steps` random-action
  steps: (state, key) -> (state, total reward). Start from `init(key)`."""
  env = AutoReset(env)

  def init(key):
    return parallel.shard(jax.vmap(env.reset)(jax.random.split(key, num_envs)))

  def run(state, key):
    def one_step(state, step_key):
      keys = jax.random.split(step_key, num_envs)
      action = jax.vmap(random_policy, in_axes=(0, 0, None))(state.obs, keys, env.action_size)
      state = jax.vmap(env.step)(state, action)
      return state, state.reward.sum()
    state, rewards = jax.lax.scan(one_step, state, jax.random.split(key, steps))
    return state, rewards.sum()

  return jax.jit(init), jax.jit(run, donate_argnums=0)
