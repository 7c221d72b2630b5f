"""The compiled trainer: one TrainState pytree, and `chunk`, a single jitted scan.

An iteration collects `unroll_length` steps of `num_envs` envs, inserts them into the replay and
runs replay_ratio * num_envs * unroll_length / batch_size updates. Every leaf has a leading axis
of S members (a sweep; a single run is one), laid out over the local devices by `layout`.
"""

from __future__ import annotations

import functools
import math
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

from mjx_hopper.agents.base import Agent
from mjx_hopper.core import kept, replay, rollout
from mjx_hopper.process import parallel
from mjx_hopper.envs import EpisodeStarts, LocomotionEnv
from mjx_hopper.settings.training import TrainConfig

AXIS = "devices"    # a member's devices: its envs, replay and batches are split over them
MEMBERS = "members"


class TrainState(NamedTuple):
  """Everything a run needs to continue; every leaf has a leading axis of S members."""

  agent: Any                     # the agent's own pytree (params, ..., hparams)
  replay: replay.ReplayState     # leaves (rows, num_envs, ...)
  env: Any                       # batch of EpisodeStarts env states, leading axis num_envs
  episode_return: jax.Array      # (num_envs,) return so far of each env's current episode
  key: jax.Array
  iteration: jax.Array           # () int32 iterations done
  updates: jax.Array             # () int32 learner updates done
  replay_ratio: jax.Array        # () float32 samples drawn per transition inserted


class Trainer(NamedTuple):
  """Compiled functions of one (env, agent, config, number of members S).

  init(seeds (S,), hparams=None, begin=True) -> TrainState: each member from
    jax.random.PRNGKey(seed); hparams: {name: (S,)} of the agent's dynamic settings and
    "replay_ratio", defaulting to the config's; begin=False: its envs blank, as `refill` begins
    them (the state's shapes, without tracing the refill).
  chunk(state) -> (state, metrics (S,)): `iterations_per_chunk` iterations; metrics: the agent's
    metrics averaged over the chunk, "episodes" ended, their mean "episode_return" (NaN if
    none) and "learning".
  refill(env states, begin) -> env states: fresh episode starts (EpisodeStarts), made after each
    chunk for the next; with `begin` (a bool array), new episodes from them, as `init` makes its
    states, so that the reset is in this program alone.
  evaluate(agent_states, keys) -> "return", "length" (S, episodes).
  shardings: each TrainState part's NamedSharding.
  """

  init: Callable[..., TrainState]
  chunk: jax.stages.Wrapped
  refill: jax.stages.Wrapped
  evaluate: jax.stages.Wrapped
  config: TrainConfig
  env: LocomotionEnv
  agent: Agent
  num_members: int
  shardings: TrainState          # of NamedSharding

  def env_steps(self, state: TrainState) -> int:
    """The env steps that `state` has trained, every member's alike."""
    return iterations(state) * self.config.steps_per_iteration

  def train_chunk(self, state: TrainState) -> tuple[TrainState, dict]:
    """A chunk, then fresh episode starts for the next: (state, metrics)."""
    state, metrics = self.chunk(state)
    return state._replace(env=self.refill(state.env, np.False_)), metrics


def mesh_shape(num_members: int, num_devices: int) -> tuple[int, int]:
  """(member groups, devices per member) for S members on D devices: gcd(S, D) groups."""
  groups = math.gcd(num_members, num_devices)
  return groups, num_devices // groups


class Layout(NamedTuple):
  """gcd(S, D) groups of `group_size` devices, each holding `local_members` members, whose
  envs, replay and batches split over the group."""

  mesh: Mesh
  local_members: int
  group_size: int
  specs: TrainState       # each part's PartitionSpec
  shardings: TrainState   # each part's NamedSharding

  @property
  def axis(self) -> str | None:
    """The mapped axis of a member's devices; None for a member on one device."""
    return AXIS if self.group_size > 1 else None

  def device_index(self):
    """This device's place among its member's devices (0 for a member on one device)."""
    return jax.lax.axis_index(AXIS) if self.axis else 0

  def total(self, x):
    """`x` summed over a member's devices."""
    return jax.lax.psum(x, AXIS) if self.axis else x

  def each_member(self, fn):
    """`fn` of one member, over this device's members."""
    return rollout.per_member(fn, self.local_members)


def layout(num_members: int, devices: list) -> Layout:
  """The mesh, and where each part of a TrainState lives on it."""
  groups, group_size = mesh_shape(num_members, len(devices))
  mesh = parallel.mesh(np.array(devices).reshape(groups, group_size), (MEMBERS, AXIS))

  def member_spec(*axes):
    return P(MEMBERS, *axes)

  specs = TrainState(agent=member_spec(),
                     replay=replay.ReplayState(member_spec(None, AXIS), member_spec(),
                                               member_spec()),
                     env=member_spec(AXIS), episode_return=member_spec(AXIS),
                     key=member_spec(), iteration=member_spec(), updates=member_spec(),
                     replay_ratio=member_spec())
  shardings = jax.tree.map(lambda spec: NamedSharding(mesh, spec), specs,
                           is_leaf=lambda x: isinstance(x, P))
  return Layout(mesh, num_members // groups, group_size, specs, shardings)


def make_trainer(env: LocomotionEnv, agent: Agent, cfg: TrainConfig, eval_episodes: int = 16,
                 num_members: int = 1, dynamic_updates: bool = False,
                 devices: list | None = None, identity: str | None = None) -> Trainer:
  """The compiled trainer of `num_members` members on `devices` (default: every process's).

  With `dynamic_updates` each member's update count follows its own replay_ratio, up to `cfg`'s;
  without, all run `cfg`'s. With `identity` (a text naming the env, agent and settings, the
  same in every process: `trainers.assemble`'s), its programs are kept as traced (`kept`).
  """
  where = layout(num_members, list(jax.devices() if devices is None else devices))
  cfg.check(where.group_size)
  train_env = EpisodeStarts.for_steps(env, cfg.unroll_length * cfg.iterations_per_chunk)
  refill = _make_refill(train_env, where, identity)
  return Trainer(_make_init(train_env, agent, cfg, where, num_members, refill, identity),
                 _make_chunk(train_env, agent, cfg, where, dynamic_updates, identity), refill,
                 rollout.make_evaluate(env, agent, eval_episodes, num_members, where.mesh,
                                       identity),
                 cfg, env, agent, num_members, where.shardings)


def _make_init(train_env: EpisodeStarts, agent: Agent, cfg: TrainConfig, where: Layout,
               num_members: int, refill, identity: str | None):
  """Trainer.init: the members' fresh TrainState, placed on the mesh: its envs blank, then
  begun by `refill`."""
  env = train_env.env

  def init_member(seed, hp):
    agent_key, env_key, key = jax.random.split(jax.random.PRNGKey(seed), 3)
    hp = dict(hp)
    ratio = hp.pop("replay_ratio")
    env_state = jax.vmap(train_env.blank)(jax.random.split(env_key, cfg.num_envs))
    return TrainState(
        agent=agent.init(agent_key, hp),
        replay=replay.init(cfg.replay_rows, cfg.num_envs, env.observation_size,
                           env.action_size),
        env=env_state, episode_return=jnp.zeros(cfg.num_envs), key=key,
        iteration=jnp.zeros((), jnp.int32), updates=jnp.zeros((), jnp.int32),
        replay_ratio=jnp.asarray(ratio, jnp.float32))

  compiled_init = kept.jit(jax.vmap(init_member), identity, "init_member",
                           exported=rollout.exported(env), out_shardings=where.shardings)

  def init(seeds, hparams=None, begin=True):
    # NumPy until the one compiled call: eager JAX here would compile programs of its own.
    seeds = np.atleast_1d(np.asarray(seeds))
    if seeds.shape != (num_members,) or not np.issubdtype(seeds.dtype, np.integer):
      raise ValueError(f"init takes {num_members} integer seeds (one per member), got {seeds!r}")
    defaults = {**agent.hparams, "replay_ratio": np.float32(cfg.replay_ratio)}
    unknown = sorted(set(hparams or {}) - set(defaults))
    if unknown:
      raise ValueError(f"unknown dynamic settings {unknown}; this agent's are {sorted(defaults)}")
    values = {**defaults, **(hparams or {})}
    batched = {k: np.broadcast_to(np.asarray(v, defaults[k].dtype), (num_members,))
               for k, v in values.items()}
    state = compiled_init(seed_bits(seeds), batched)
    return state._replace(env=refill(state.env, np.True_)) if begin else state
  return init


def _make_refill(train_env: EpisodeStarts, where: Layout, identity: str | None):
  """Trainer.refill: each env's fresh episode starts, made where its env lives."""
  def refill(env_states, begin):
    return where.each_member(jax.vmap(lambda s: train_env.refill(s, begin)))(env_states)
  replicated = NamedSharding(where.mesh, P())
  return kept.jit(jax.shard_map(refill, mesh=where.mesh, in_specs=(where.specs.env, P()),
                                out_specs=where.specs.env, check_vma=False),
                  identity, "refill", exported=rollout.exported(train_env),
                  in_shardings=(where.shardings.env, replicated),
                  out_shardings=where.shardings.env, donate_argnums=0)


def collect(agent: Agent, train_env: EpisodeStarts, unroll_length: int, agent_state, env_state,
            episode_return, key):
  """One member's envs' steps: (env, return, steps (T, n, ...), ended (count, return sum))."""
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
      one, (env_state, episode_return), jax.random.split(key, unroll_length))
  return env_state, episode_return, steps, jax.tree.map(jnp.sum, ended)


def learn(agent: Agent, cfg: TrainConfig, where: Layout, dynamic_updates: bool, agent_state,
          buffer, key, n_updates):
  """One member's updates of an iteration, of which the first `n_updates` count: (agent state,
  their mean metrics)."""
  n_step, discount = agent.transitions(agent_state.hparams)
  max_updates = cfg.updates_per_iteration

  def one(agent_state, x):
    i, update_key = x
    sample_key = jax.random.fold_in(update_key, where.device_index())
    batch = replay.sample(buffer, sample_key, cfg.batch_size // where.group_size, n_step,
                          discount, window=agent.n_step)
    new, metrics = agent.update(agent_state, batch, update_key, axis_name=where.axis)
    if dynamic_updates:
      new = jax.tree.map(lambda a, b: jnp.where(i < n_updates, a, b), new, agent_state)
    return new, metrics
  steps = jnp.arange(max_updates)
  agent_state, metrics = jax.lax.scan(one, agent_state,
                                      (steps, jax.random.split(key, max_updates)))
  weight = (steps < n_updates) / n_updates
  return agent_state, jax.tree.map(lambda m: jnp.sum(m * weight), metrics)


def _metric_shapes(env: LocomotionEnv, agent: Agent):
  """The shapes of one update's metrics."""
  def shape(*dims):
    return jax.ShapeDtypeStruct(dims, jnp.float32)
  example = replay.Transition(shape(1, env.observation_size), shape(1, env.action_size),
                              shape(1), shape(1), shape(1, env.observation_size))
  key = jax.ShapeDtypeStruct((2,), jnp.uint32)
  return jax.eval_shape(lambda s, batch, k: agent.update(s, batch, k)[1],
                        jax.eval_shape(agent.init, key), example, key)


def _make_chunk(train_env: EpisodeStarts, agent: Agent, cfg: TrainConfig, where: Layout,
                dynamic_updates: bool, identity: str | None):
  """Trainer.chunk: `iterations_per_chunk` iterations, under shard_map over the mesh."""
  each_member = where.each_member
  member_collect = functools.partial(collect, agent, train_env, cfg.unroll_length)
  learn_if_filled = functools.partial(_learn_if_filled, agent, cfg, where, dynamic_updates,
                                      _metric_shapes(train_env.env, agent))

  def iteration(state: TrainState, _):
    """The local members' collection and insert, then their updates."""
    key, act_key, learn_key = each_member(lambda k: tuple(jax.random.split(k, 3)))(state.key)
    act_key = each_member(lambda k: jax.random.fold_in(k, where.device_index()))(act_key)
    env_state, ep_return, steps, (ended, ended_return) = each_member(member_collect)(
        state.agent, state.env, state.episode_return, act_key)
    buffer = each_member(replay.insert)(state.replay, steps)
    agent_state, metrics, learning, n_updates = learn_if_filled(state, buffer, learn_key)
    new = state._replace(agent=agent_state, replay=buffer, env=env_state,
                         episode_return=ep_return, key=key, iteration=state.iteration + 1,
                         updates=state.updates + learning * n_updates)
    learning = jnp.broadcast_to(learning, (where.local_members,))
    return new, (metrics, learning, where.total(ended), where.total(ended_return))

  def chunk(state: TrainState):
    state, (metrics, learning, ended, ended_return) = jax.lax.scan(
        iteration, state, None, length=cfg.iterations_per_chunk)
    weight = learning / jnp.maximum(learning.sum(0), 1)
    out = {k: jnp.sum(v * weight, 0) for k, v in metrics.items()}
    out.update(episodes=ended.sum(0), episode_return=ended_return.sum(0) / ended.sum(0),
               learning=learning[-1].astype(jnp.float32))
    return state, out

  # Explicit shardings, the same in and out, so that a chunk's output feeds the next call
  # without a second compilation.
  per_member_out = NamedSharding(where.mesh, P(MEMBERS))
  return kept.jit(
      jax.shard_map(chunk, mesh=where.mesh, in_specs=(where.specs,),
                    out_specs=(where.specs, P(MEMBERS)), check_vma=False),
      identity, "chunk", exported=rollout.exported(train_env), in_shardings=(where.shardings,),
      out_shardings=(where.shardings, per_member_out), donate_argnums=0)


def _learn_if_filled(agent: Agent, cfg: TrainConfig, where: Layout, dynamic_updates: bool,
                     metric_shapes, state: TrainState, buffer, learn_key):
  """The local members' updates of an iteration, once their replay (`buffer`, after this
  iteration's insert) holds `min_replay` transitions: (agent states, metrics, whether they
  learned, the updates that count)."""
  each_member = where.each_member
  member_learn = functools.partial(learn, agent, cfg, where, dynamic_updates)
  # The members insert in lockstep, so they all start learning at the same iteration: one
  # branch for all of them. (A branch per member would be a select under the member vmap,
  # which runs the updates of members that are not learning yet.)
  learning = buffer.filled[0] >= max(-(-cfg.min_replay // cfg.num_envs), agent.n_step)
  zeros = jax.tree.map(lambda s: jnp.zeros((where.local_members,) + s.shape, s.dtype),
                       metric_shapes)
  if dynamic_updates:
    n_updates = each_member(lambda ratio: jnp.round(
        ratio * cfg.steps_per_iteration / cfg.batch_size).astype(jnp.int32))(state.replay_ratio)
    update, args = each_member(member_learn), (state.agent, buffer, learn_key, n_updates)
  else:
    n_updates = cfg.updates_per_iteration
    update = each_member(lambda a, b, k: member_learn(a, b, k, n_updates))
    args = (state.agent, buffer, learn_key)
  agent_state, metrics = jax.lax.cond(learning, update, lambda a, *_: (a, zeros), *args)
  return agent_state, metrics, learning, n_updates


def seed_bits(seeds) -> np.ndarray:
  """Integer seeds as the uint32 that jax.random.PRNGKey and fold_in keep of them, for a
  compiled program to take as NumPy."""
  return (np.asarray(seeds, np.int64) % 2**32).astype(np.uint32)


def iterations(state: TrainState) -> int:
  """Iterations done (the same for every member), read from this process's members."""
  count = state.iteration
  if isinstance(count, jax.Array):
    count = count.addressable_data(0)
  return int(np.asarray(jax.device_get(count)).reshape(-1)[0])
