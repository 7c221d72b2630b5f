"""Batched, jit-compiled rollouts of an env: whole episodes (a policy's, and an agent's
evaluation), and steady-state stepping."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from jax.sharding import Mesh

from mjx_hopper.agents.base import Agent
from mjx_hopper.core import kept
from mjx_hopper.process import parallel
from mjx_hopper.envs import EpisodeStarts, LocomotionEnv

Policy = Callable[[jax.Array, jax.Array], jax.Array]  # (obs (O,), key) -> action (A,)


def random_policy(action_size: int) -> Policy:
  """Uniform random actions in [-1, 1]."""
  return lambda obs, key: jax.random.uniform(key, (action_size,), minval=-1.0, maxval=1.0)


def zero_policy(action_size: int) -> Policy:
  """A policy whose every action is zero: the robot unactuated."""
  return lambda obs, key: jnp.zeros(action_size)


def episodes(env: LocomotionEnv, policy: Policy, key: jax.Array, num_episodes: int,
             record_qpos: bool = False, record_rewards: bool = False,
             devices=None) -> dict[str, jax.Array]:
  """Runs `num_episodes` episodes to their end, spread over `devices`; jit with all but `key`
  static. Results do not depend on the number of devices.

  Returns "length", "return" and each reward term's mean per step, all (num_episodes,); with
  `record_qpos`, episode 0's "qpos" (episode_steps + 1, nq); with `record_rewards`, "rewards"
  (num_episodes, episode_steps), 0 after an episode ends.
  """
  reset_key, policy_key = jax.random.split(key)
  # The first states come into the episodes' program as the chunk's env states come into the
  # chunk's, so that both share one trace of the env's step.
  first = parallel.per_device(jax.vmap(env.reset), num_episodes, devices)(
      jax.random.split(reset_key, num_episodes))
  result = parallel.per_device(
      lambda state, keys: _local_episodes(env, policy, state, keys, record_qpos, record_rewards),
      num_episodes, devices)(first, jax.random.split(policy_key, num_episodes))
  if record_qpos:
    result["qpos"] = result["qpos"][0]
  return result


def evaluate(env: LocomotionEnv, agent: Agent, agent_state, key: jax.Array,
             num_episodes: int, record_qpos: bool = False,
             devices: list | Mesh | None = None) -> dict[str, jax.Array]:
  """`num_episodes` episodes of one member's deterministic policy, over `devices`.

  Returns "return" and "length" (num_episodes,), each reward term's mean, and with `record_qpos`
  episode 0's "qpos"."""
  return episodes(env, lambda obs, _: agent.policy(agent_state, obs), key, num_episodes,
                  record_qpos=record_qpos, devices=devices)


def per_member(fn, local_members: int):
  """`fn` over a leading axis of `local_members`: vmap, or plain code for one member (a single
  run's program)."""
  if local_members > 1:
    return jax.vmap(fn)

  def one(*args):
    out = fn(*jax.tree.map(lambda x: x[0], args))
    return jax.tree.map(lambda x: x[None], out)
  return one


def exported(env) -> bool:
  """Whether `env`'s programs go through `jax.export` (`kept`): not where its step calls the
  host."""
  return not getattr(env, "calls_host", False)


def make_evaluate(env: LocomotionEnv, agent: Agent, eval_episodes: int, num_members: int,
                  devices: list | Mesh | None = None, identity: str | None = None):
  """Trainer.evaluate: each member's `eval_episodes` episodes, jitted, over `devices` (a
  list, or the trainer's mesh: `parallel.per_device`); kept as traced under `identity`."""
  # One member's evaluation as plain code (vmap of one traces much slower), several under vmap.
  return kept.jit(per_member(
      lambda s, k: evaluate(env, agent, s, k, eval_episodes, devices=devices), num_members),
      identity, "evaluate", exported=exported(env))


def _local_episodes(env, policy, state, policy_keys, record_qpos, record_rewards):
  """`episodes` on one device's share of (first states, policy keys)."""
  zeros = jnp.zeros(policy_keys.shape[0])
  totals = {"length": zeros, "return": zeros, **{k: zeros for k in state.metrics}}
  qpos = jnp.zeros((env.episode_steps + 1, env.mj_model.nq)) + state.pipeline_state.qpos[0]
  rewards = jnp.zeros((policy_keys.shape[0], env.episode_steps)) if record_rewards else None

  def running(carry):
    t, state = carry[:2]
    return (t < env.episode_steps) & (state.done == 0).any()

  def one_step(carry):
    t, state, totals, qpos, rewards = carry
    step_keys = jax.vmap(jax.random.fold_in, (0, None))(policy_keys, t)
    action = jax.vmap(policy)(state.obs, step_keys)
    live = state.done == 0
    nxt = jax.vmap(env.step)(state, action)
    nxt = jax.tree.map(lambda new, old: _where_rows(live, new, old), nxt, state)
    totals = {"length": totals["length"] + live, "return": totals["return"] + live * nxt.reward,
              **{k: totals[k] + live * v for k, v in nxt.metrics.items()}}
    if record_qpos:
      later = jnp.arange(qpos.shape[0])[:, None] > t
      qpos = jnp.where(later, nxt.pipeline_state.qpos[0], qpos)
    if record_rewards:
      rewards = rewards.at[:, t].set(live * nxt.reward)
    return t + 1, nxt, totals, qpos, rewards

  _, _, totals, qpos, rewards = jax.lax.while_loop(
      running, one_step, (jnp.zeros((), jnp.int32), state, totals, qpos, rewards))
  result = {"length": totals["length"].astype(jnp.int32), "return": totals["return"]}
  for name in state.metrics:
    result[name] = totals[name] / jnp.maximum(totals["length"], 1)
  if record_qpos:
    result["qpos"] = qpos[None]  # one per device; `episodes` keeps the first
  if record_rewards:
    result["rewards"] = rewards
  return result


def _where_rows(rows: jax.Array, new: jax.Array, old: jax.Array) -> jax.Array:
  return jnp.where(rows.reshape(rows.shape + (1,) * (new.ndim - 1)), new, old)


def make_stepper(env: LocomotionEnv, num_envs: int, steps: int):
  """Compiled `init(key) -> state` and `run(state, key) -> (state, summed reward)`, which steps
  `num_envs` auto-resetting envs `steps` times with random actions over the local devices, then
  makes fresh episode starts: as a training chunk and its refill do."""
  env = EpisodeStarts.for_steps(env, steps)
  policy = random_policy(env.action_size)

  def init(key):
    return parallel.shard(jax.vmap(env.reset)(jax.random.split(key, num_envs)))

  def local_run(state, env_keys):
    def one_step(state, t):
      step_keys = jax.vmap(jax.random.fold_in, (0, None))(env_keys, t)
      state = jax.vmap(env.step)(state, jax.vmap(policy)(state.obs, step_keys))
      return state, state.reward
    state, rewards = jax.lax.scan(one_step, state, jnp.arange(steps))
    return jax.vmap(env.refill)(state), rewards.sum(0)

  def run(state, key):
    state, rewards = parallel.per_device(local_run, num_envs)(
        state, jax.random.split(key, num_envs))
    return state, rewards.sum()

  return jax.jit(init), jax.jit(run, donate_argnums=0)


def demo(env_id, num_envs: int = 1024, steps: int = 500, seed: int = 0, out: str = "runs/demo",
         print_fn=print) -> str:
  """Steps `num_envs` envs of `env_id` (a name, class or instance) `steps` times with random
  actions, printing env steps/s, then films one random-action episode. Returns the mp4's path."""
  import os
  import time

  import numpy as np

  from mjx_hopper import envs
  from mjx_hopper.envs import render

  env = envs.make(env_id)
  envs.check_task(env)
  name = envs.task_id(type(env)).rpartition(":")[2]
  print_fn(f"{name}: observation {env.observation_size}, action {env.action_size}, control dt "
           f"{env.dt} s; devices: {jax.devices()}")
  chunk = 50
  init, run = make_stepper(env, num_envs, chunk)
  key = jax.random.PRNGKey(seed)
  state = init(key)
  t0 = time.perf_counter()
  run = run.lower(state, key).compile()
  print_fn(f"compiled a {chunk}-step chunk of {num_envs} envs in {time.perf_counter() - t0:.1f} s")
  t0 = time.perf_counter()
  for i in range(max(1, steps // chunk)):
    state, reward = run(state, jax.random.fold_in(key, i))
    jax.block_until_ready(reward)
    done = (i + 1) * chunk * num_envs
    print_fn(f"  {done:>10,} env steps  {done / (time.perf_counter() - t0):>10,.0f} env steps/s  "
             f"mean reward {float(reward) / (chunk * num_envs):+.3f}")
  stats = jax.jit(lambda k: episodes(env, random_policy(env.action_size), k, 1,
                                     record_qpos=True))(key)
  length = int(stats["length"][0])
  os.makedirs(out, exist_ok=True)
  path = render.write_mp4(os.path.join(out, f"{name.lower()}_random.mp4"),
                          env.render(np.asarray(stats["qpos"][:length + 1])), fps=1 / env.dt)
  print_fn(f"random-action episode: {length} steps, return {float(stats['return'][0]):.1f}; "
           f"video: {path}")
  return path
