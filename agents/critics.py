"""The two kinds of critic the agents choose between, behind one interface: a scalar Q (DDPG,
MPO) and a categorical distribution over fixed atoms (D4PG, DMPO).

A head says how many outputs the critic network has, how to read a Q-value from them, and how to
build and fit a TD target. Targets average over a leading axis of S sampled next actions (S = 1
for a deterministic policy): the scalar target is r + d * mean_s Q(s', a'_s); the categorical one
is the projection of the mixture of the S next-state distributions, which equals the average of
their projections since the projection is linear in the probabilities.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from mjx_hopper.agents import distributional


class Head(NamedTuple):
  """A critic's head: its network's output size, and how to read a value from its outputs and
  build and fit a TD target."""

  num_outputs: int                              # 1: scalar (the network returns (...,))
  value: Callable[[jax.Array], jax.Array]       # outputs -> (...,) Q
  target: Callable[..., jax.Array]              # (outputs (S, B, ...), reward, discount) -> target
  loss: Callable[[jax.Array, jax.Array], jax.Array]  # (outputs, target) -> (B,) loss


def scalar() -> Head:
  """A scalar Q, fitted by half the squared TD error (DDPG, MPO)."""

  def target(next_q, reward, discount):
    return reward + discount * next_q.mean(axis=0)
  return Head(1, lambda q: q, target, lambda q, target: 0.5 * jnp.square(q - target))


def categorical(vmin: float, vmax: float, num_atoms: int) -> Head:
  """A categorical distribution over `num_atoms` atoms from vmin to vmax, fitted by the
  cross-entropy to the projected target (D4PG, DMPO)."""
  # The support is made where it is used, inside the compiled update: made here from numbers,
  # it would be a program of its own, compiled eagerly.
  def support():
    return distributional.atoms(vmin, vmax, num_atoms)

  def target(next_logits, reward, discount):
    probs = jax.nn.softmax(next_logits).mean(axis=0)
    return distributional.project(support(), probs, reward, discount)
  distributional.check_concrete_support(vmin, vmax, num_atoms)
  return Head(num_atoms, lambda logits: distributional.mean(support(), logits), target,
              distributional.cross_entropy)
