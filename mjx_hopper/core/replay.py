"""A jittable uniform replay: a ring of rows (rows, num_envs, ...) of env steps, from which
n-step transitions are built as they are sampled.

A transition stops at the step that ended its episode, and its discount is gamma^m times the
env discounts, so time limits bootstrap and terminations do not.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class Step(NamedTuple):
  """One env step, as stored. Shapes are per env."""

  obs: jax.Array        # (O,) observation the action was taken in
  action: jax.Array     # (A,)
  reward: jax.Array     # ()
  discount: jax.Array   # () env discount: 0 if the episode terminated here, else 1
  done: jax.Array       # () 1 if the episode ended here (termination or time limit)
  next_obs: jax.Array   # (O,) true next observation (the final one when the episode ended)


class Transition(NamedTuple):
  """An n-step transition, as the learners see it (batch shapes lead)."""

  obs: jax.Array        # (..., O)
  action: jax.Array     # (..., A)
  reward: jax.Array     # (...,) discounted sum of up to n rewards
  discount: jax.Array   # (...,) gamma^m * product of env discounts; 0 after a termination
  next_obs: jax.Array   # (..., O) observation to bootstrap from


class ReplayState(NamedTuple):
  """A ring buffer of steps, rows x num_envs, with where the next insert goes."""

  steps: Step           # leaves (rows, num_envs, ...)
  position: jax.Array   # () int32 row the next insert starts at
  filled: jax.Array     # () int32 rows holding data, at most `rows`


def init(rows: int, num_envs: int, obs_size: int, action_size: int) -> ReplayState:
  """An empty buffer of rows x num_envs steps (float32)."""
  def zeros(*shape):
    return jnp.zeros((rows, num_envs, *shape), jnp.float32)
  steps = Step(obs=zeros(obs_size), action=zeros(action_size), reward=zeros(), discount=zeros(),
               done=zeros(), next_obs=zeros(obs_size))
  return ReplayState(steps, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))


def insert(state: ReplayState, steps: Step) -> ReplayState:
  """Writes T rows of steps (T, num_envs, ...); the ring's rows are a multiple of T."""
  rows = state.steps.obs.shape[0]
  t = steps.obs.shape[0]
  if rows % t:
    raise ValueError(f"replay rows ({rows}) must be a multiple of the rows per insert ({t})")
  new = jax.tree.map(lambda buf, x: jax.lax.dynamic_update_slice_in_dim(buf, x, state.position,
                                                                        axis=0),
                     state.steps, steps)
  return ReplayState(new, (state.position + t) % rows, jnp.minimum(state.filled + t, rows))


def can_sample(state: ReplayState, n_step: int) -> jax.Array:
  """() bool: whether the buffer holds the `n_step` rows a sample needs."""
  return state.filled >= n_step


def sample(state: ReplayState, key: jax.Array, batch_size: int, n_step, gamma,
           window: int | None = None) -> Transition:
  """`batch_size` n-step transitions from uniform starts; needs `can_sample(state, n_step)`.

  `n_step` and `gamma` may be arrays; `window` (default `n_step`) is the static number of rows
  read, at least any n_step.
  """
  window = n_step if window is None else window
  rows, num_envs = state.steps.obs.shape[:2]
  row_key, env_key = jax.random.split(key)
  oldest = (state.position - state.filled) % rows
  starts = jax.random.randint(row_key, (batch_size,), 0, state.filled - n_step + 1)
  row_idx = (oldest + starts[:, None] + jnp.arange(window)) % rows      # (B, window)
  env_idx = jax.random.randint(env_key, (batch_size,), 0, num_envs)[:, None]
  steps = jax.tree.map(lambda x: x[row_idx, env_idx], state.steps)      # leaves (B, window, ...)
  return n_step_transition(steps, gamma, n_step)


def n_step_transition(window: Step, gamma, n_step=None) -> Transition:
  """Transitions from the first `n_step` (default W) of windows of steps (B, W, ...)."""
  w = window.reward.shape[-1]
  not_done = 1.0 - window.done
  # live[k]: no episode ended in steps 0..k-1, so step k belongs to the transition.
  live = jnp.concatenate([jnp.ones_like(not_done[:, :1]), jnp.cumprod(not_done[:, :-1], -1)], -1)
  if n_step is not None:
    live = live * (jnp.arange(w) < n_step)
  powers = gamma ** jnp.arange(w, dtype=jnp.float32)
  last = (jnp.sum(live, -1) - 1).astype(jnp.int32)                      # index of the final step
  take_last = jax.vmap(lambda x, i: x[i])
  return Transition(
      obs=window.obs[:, 0],
      action=window.action[:, 0],
      reward=jnp.sum(live * powers * window.reward, -1),
      discount=gamma ** (last + 1).astype(jnp.float32) * take_last(window.discount, last),
      next_obs=take_last(window.next_obs, last))
