"""The compiled trainer: one TrainState pytree, and `train_chunk`, a single jitted scan.

Each iteration of a chunk collects `unroll_length` steps from each of `num_envs` auto-resetting
envs with the agent's exploring policy, inserts them into the replay, and runs K learner
updates on batches of n-step transitions, where K = replay_ratio * num_envs * unroll_length /
batch_size (the replay ratio is samples drawn per transition inserted).

Devices: the whole iteration runs under `shard_map` over every local device. Each device steps
its share of the envs, keeps their steps in its share of the replay, and samples its share of
each batch from it; the learner is data-parallel (gradients averaged over devices, parameters
replicated). With one device it is plain single-device code.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

from mjx_hopper import replay, rollout
from mjx_hopper.agents.base import Agent
from mjx_hopper.envs import AutoReset, LocomotionEnv

AXIS = "devices"


@dataclasses.dataclass(frozen=True)
class TrainConfig:
  """How to train. Sizes count transitions (one env step of one env).

  The defaults are the settings that reached 2,000 on Hopper in the fewest CPU-affordable
  env steps and updates with D4PG's cpu preset (BENCHMARKS.md, "Choosing the CPU settings").
  """

  num_envs: int = 512
  unroll_length: int = 4         # env steps per env per iteration
  batch_size: int = 256
  replay_ratio: float = 4.0      # samples drawn per transition inserted
  replay_size: int = 1_000_000   # transitions kept
  min_replay: int = 20_000       # transitions collected before learning starts
  iterations_per_chunk: int = 25

  @property
  def steps_per_iteration(self) -> int:
    return self.num_envs * self.unroll_length

  @property
  def updates_per_iteration(self) -> int:
    return round(self.replay_ratio * self.steps_per_iteration / self.batch_size)

  def check(self, num_devices: int = 1) -> None:
    """Raises ValueError naming the first bad setting."""
    for name in ("num_envs", "unroll_length", "batch_size", "iterations_per_chunk"):
      value = getattr(self, name)
      if not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if self.replay_size < self.batch_size:
      raise ValueError(f"replay_size ({self.replay_size}) must be at least batch_size "
                       f"({self.batch_size})")
    if self.min_replay > self.replay_size:
      raise ValueError(f"min_replay ({self.min_replay}) must be at most replay_size "
                       f"({self.replay_size})")
    updates = self.replay_ratio * self.steps_per_iteration / self.batch_size
    if self.replay_ratio <= 0 or abs(updates - round(updates)) > 1e-9:
      raise ValueError(
          f"replay_ratio * num_envs * unroll_length / batch_size must be a whole number of "
          f"updates >= 1, got {self.replay_ratio} * {self.num_envs} * {self.unroll_length} / "
          f"{self.batch_size} = {updates:g}")
    for name in ("num_envs", "batch_size"):
      if getattr(self, name) % num_devices:
        raise ValueError(f"{name} ({getattr(self, name)}) must divide evenly over the "
                         f"{num_devices} devices")

  def replay_rows(self) -> int:
    """Rows of the replay ring: at least replay_size / num_envs, a multiple of the unroll."""
    rows = -(-self.replay_size // self.num_envs)
    return -(-rows // self.unroll_length) * self.unroll_length


class TrainState(NamedTuple):
  """Everything a run needs to continue: orbax saves it whole."""

  agent: Any                     # the agent's own pytree (params, targets, optimizer states)
  replay: replay.ReplayState     # leaves (rows, num_envs, ...)
  env: Any                       # batch of AutoReset env states, leading axis num_envs
  episode_return: jax.Array      # (num_envs,) return so far of each env's current episode
  key: jax.Array
  iteration: jax.Array           # () int32 iterations done
  updates: jax.Array             # () int32 learner updates done


class Trainer(NamedTuple):
  """Compiled functions of one (env, agent, config).

  init(key) -> TrainState
  train_chunk(state) -> (state, metrics): `iterations_per_chunk` iterations; metrics are the
    agent's, averaged over the chunk's updates, plus "episodes" (count ended in the chunk),
    "episode_return" (their mean return; NaN if none ended) and "learning" (1 once updating).
  evaluate(agent_state, key) -> per-episode "return", "length" (see `evaluate`).
  """

  init: Any
  train_chunk: Any
  evaluate: Any
  config: TrainConfig
  env: LocomotionEnv
  agent: Agent


def make_trainer(env: LocomotionEnv, agent: Agent, cfg: TrainConfig,
                 eval_episodes: int = 16) -> Trainer:
  devices = jax.local_devices()
  cfg.check(len(devices))
  mesh = Mesh(devices, (AXIS,))
  train_env = AutoReset(env)
  rows = cfg.replay_rows()
  min_rows = max(-(-cfg.min_replay // cfg.num_envs), agent.n_step)
  local_batch = cfg.batch_size // len(devices)
  n_updates = cfg.updates_per_iteration

  specs = TrainState(agent=P(), replay=replay.ReplayState(P(None, AXIS), P(), P()),
                     env=P(AXIS), episode_return=P(AXIS), key=P(), iteration=P(), updates=P())

  def init(key):
    agent_key, env_key, key = jax.random.split(key, 3)
    env_state = jax.vmap(train_env.reset)(jax.random.split(env_key, cfg.num_envs))
    return TrainState(
        agent=agent.init(agent_key),
        replay=replay.init(rows, cfg.num_envs, env.observation_size, env.action_size),
        env=env_state, episode_return=jnp.zeros(cfg.num_envs), key=key,
        iteration=jnp.zeros((), jnp.int32), updates=jnp.zeros((), jnp.int32))

  shardings = jax.tree.map(lambda spec: NamedSharding(mesh, spec), specs,
                           is_leaf=lambda x: isinstance(x, P))

  def collect(agent_state, env_state, episode_return, key):
    """unroll_length steps of this device's envs: (env, return, steps (T, n, ...), ended
    episodes' (count, return sum))."""
    def one(carry, step_key):
      env_state, ep_return = carry
      action = agent.act(agent_state, env_state.obs, step_key)
      nxt = jax.vmap(train_env.step)(env_state, action)
      terminated = nxt.done * (1.0 - nxt.info["truncation"])
      step = replay.Step(obs=env_state.obs, action=action, reward=nxt.reward,
                         discount=1.0 - terminated, done=nxt.done,
                         next_obs=nxt.info["final_obs"])
      ep_return = ep_return + nxt.reward
      ended = (jnp.sum(nxt.done), jnp.sum(nxt.done * ep_return))
      return (nxt, ep_return * (1.0 - nxt.done)), (step, ended)
    (env_state, episode_return), (steps, ended) = jax.lax.scan(
        one, (env_state, episode_return), jax.random.split(key, cfg.unroll_length))
    return env_state, episode_return, steps, jax.tree.map(jnp.sum, ended)

  def learn(agent_state, buffer, key):
    def one(agent_state, update_key):
      sample_key = jax.random.fold_in(update_key, jax.lax.axis_index(AXIS))
      batch = replay.sample(buffer, sample_key, local_batch, agent.n_step, agent.discount)
      return agent.update(agent_state, batch, update_key, axis_name=AXIS)
    agent_state, metrics = jax.lax.scan(one, agent_state, jax.random.split(key, n_updates))
    return agent_state, jax.tree.map(jnp.mean, metrics)

  example = replay.Transition(jnp.zeros((1, env.observation_size)), jnp.zeros((1, env.action_size)),
                              jnp.zeros(1), jnp.zeros(1), jnp.zeros((1, env.observation_size)))
  key0 = jax.random.PRNGKey(0)
  metric_shapes = jax.eval_shape(lambda s: agent.update(s, example, key0)[1],
                                 jax.eval_shape(agent.init, key0))

  def iteration(state: TrainState, _):
    key, act_key, learn_key = jax.random.split(state.key, 3)
    act_key = jax.random.fold_in(act_key, jax.lax.axis_index(AXIS))
    env_state, ep_return, steps, (ended, ended_return) = collect(
        state.agent, state.env, state.episode_return, act_key)
    buffer = replay.insert(state.replay, steps)
    learning = buffer.filled >= min_rows
    zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), metric_shapes)
    agent_state, metrics = jax.lax.cond(learning, learn, lambda a, b, k: (a, zeros),
                                        state.agent, buffer, learn_key)
    new = TrainState(agent_state, buffer, env_state, ep_return, key, state.iteration + 1,
                     state.updates + learning * n_updates)
    return new, (metrics, learning, jax.lax.psum(ended, AXIS), jax.lax.psum(ended_return, AXIS))

  def chunk(state: TrainState):
    state, (metrics, learning, ended, ended_return) = jax.lax.scan(
        iteration, state, None, length=cfg.iterations_per_chunk)
    weight = learning / jnp.maximum(learning.sum(), 1)
    out = {k: jnp.sum(v * weight) for k, v in metrics.items()}
    out.update(episodes=ended.sum(), episode_return=ended_return.sum() / ended.sum(),
               learning=learning[-1].astype(jnp.float32))
    return state, out

  # Explicit shardings, the same in and out, so that a chunk's output feeds the next call
  # without a second compilation.
  train_chunk = jax.jit(jax.shard_map(chunk, mesh=mesh, in_specs=(specs,),
                                      out_specs=(specs, P()), check_vma=False),
                        in_shardings=(shardings,),
                        out_shardings=(shardings, NamedSharding(mesh, P())), donate_argnums=0)

  def evaluate_fn(agent_state, key):
    return evaluate(env, agent, agent_state, key, eval_episodes)

  return Trainer(jax.jit(init, out_shardings=shardings), train_chunk, jax.jit(evaluate_fn), cfg,
                 env, agent)


def evaluate(env: LocomotionEnv, agent: Agent, agent_state, key: jax.Array,
             num_episodes: int, record_qpos: bool = False) -> dict[str, jax.Array]:
  """Runs `num_episodes` episodes in parallel with the deterministic policy (jit it with env,
  agent and num_episodes static). Returns per-episode "return" and "length" (num_episodes,),
  the mean of each reward term, and with `record_qpos` the "qpos" of episode 0."""
  return rollout.episodes(env, lambda obs, _: agent.policy(agent_state, obs), key, num_episodes,
                          record_qpos=record_qpos)
