"""Batched, jit-compiled rollouts of an env: whole episodes, and steady-state stepping."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from mjx_hopper import parallel
from mjx_hopper.envs import AutoReset, LocomotionEnv

Policy = Callable[[jax.Array, jax.Array], jax.Array]  # (obs (O,), key) -> action (A,)


def random_policy(action_size: int) -> Policy:
  """Uniform random actions in [-1, 1]."""
  return lambda obs, key: jax.random.uniform(key, (action_size,), minval=-1.0, maxval=1.0)


def zero_policy(action_size: int) -> Policy:
  return lambda obs, key: jnp.zeros(action_size)


def episodes(env: LocomotionEnv, policy: Policy, key: jax.Array, num_episodes: int,
             record_qpos: bool = False) -> dict[str, jax.Array]:
  """Runs `num_episodes` episodes in parallel, each to its end (at most env.episode_steps),
  and stops once all have ended. Jit it with `env`, `policy` and `num_episodes` static.

  Returns per-episode arrays of shape (num_episodes,): "length", "return", and the mean per
  step of each reward term, by name. With `record_qpos`, also "qpos" of episode 0, shape
  (env.episode_steps + 1, nq), holding its last pose after it ends.
  """
  reset_key, policy_key = jax.random.split(key)
  state = parallel.shard(jax.vmap(env.reset)(jax.random.split(reset_key, num_episodes)))
  zeros = jnp.zeros(num_episodes)
  totals = {"length": zeros, "return": zeros, **{k: zeros for k in state.metrics}}
  qpos = jnp.zeros((env.episode_steps + 1, env.mj_model.nq))
  qpos = qpos + state.pipeline_state.qpos[0] if record_qpos else None

  def running(carry):
    t, state, _, _, _ = carry
    return (t < env.episode_steps) & (state.done == 0).any()

  def one_step(carry):
    t, state, totals, qpos, key = carry
    key, step_key = jax.random.split(key)
    action = jax.vmap(policy)(state.obs, jax.random.split(step_key, num_episodes))
    live = state.done == 0
    nxt = jax.vmap(env.step)(state, action)
    nxt = jax.tree.map(lambda new, old: _where_rows(live, new, old), nxt, state)
    totals = {"length": totals["length"] + live, "return": totals["return"] + live * nxt.reward,
              **{k: totals[k] + live * v for k, v in nxt.metrics.items()}}
    if qpos is not None:
      later = jnp.arange(qpos.shape[0])[:, None] > t
      qpos = jnp.where(later, nxt.pipeline_state.qpos[0], qpos)
    return t + 1, nxt, totals, qpos, key

  _, _, totals, qpos, _ = jax.lax.while_loop(
      running, one_step, (jnp.zeros((), jnp.int32), state, totals, qpos, policy_key))
  result = {"length": totals["length"].astype(jnp.int32), "return": totals["return"]}
  for name in state.metrics:
    result[name] = totals[name] / jnp.maximum(totals["length"], 1)
  if record_qpos:
    result["qpos"] = qpos
  return result


def _where_rows(rows: jax.Array, new: jax.Array, old: jax.Array) -> jax.Array:
  return jnp.where(rows.reshape(rows.shape + (1,) * (new.ndim - 1)), new, old)


def make_stepper(env: LocomotionEnv, num_envs: int, steps: int):
  """Compiled functions that step `num_envs` auto-resetting envs with random actions.

  Returns `init(key) -> state` and `run(state, key) -> (state, summed reward)`, where `run`
  advances every env by `steps` steps in one call.
  """
  env = AutoReset(env)
  policy = random_policy(env.action_size)

  def init(key):
    return parallel.shard(jax.vmap(env.reset)(jax.random.split(key, num_envs)))

  def run(state, key):
    def one_step(state, step_key):
      action = jax.vmap(policy)(state.obs, jax.random.split(step_key, num_envs))
      state = jax.vmap(env.step)(state, action)
      return state, state.reward.sum()
    state, rewards = jax.lax.scan(one_step, state, jax.random.split(key, steps))
    return state, rewards.sum()

  return jax.jit(init), jax.jit(run, donate_argnums=0)
