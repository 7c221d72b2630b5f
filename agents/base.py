"""The agent interface: a small container of pure functions, in the style of optax.

The trainer knows nothing agent-specific: it calls `init` once, `act` to collect, `update` on
sampled n-step transitions, and `policy` to evaluate. Agent state is any pytree.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax

AgentState = Any


class Agent(NamedTuple):
  """A learner as pure functions. Observations are (..., O), actions (..., A) in [-1, 1].

  init(key) -> state
  act(state, obs, key) -> action, with exploration
  policy(state, obs) -> action, deterministic (for evaluation)
  update(state, transitions, key, axis_name=None) -> (state, metrics); with `axis_name`, the
    gradients (and metrics) are averaged over that mapped axis (data-parallel learning).
  n_step, discount: how the trainer builds the n-step transitions it samples for `update`.
  """

  init: Callable[[jax.Array], AgentState]
  act: Callable[[AgentState, jax.Array, jax.Array], jax.Array]
  policy: Callable[[AgentState, jax.Array], jax.Array]
  update: Callable[..., tuple[AgentState, dict[str, jax.Array]]]
  n_step: int
  discount: float


def pmean(tree, axis_name: str | None):
  """Averages a pytree over a mapped axis, or returns it as it is when there is none."""
  return tree if axis_name is None else jax.lax.pmean(tree, axis_name)
