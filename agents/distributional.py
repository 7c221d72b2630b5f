"""Categorical value distributions over fixed atoms (C51 / D4PG): projection and loss."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def check_support(vmin: float, vmax: float, num_atoms: int) -> None:
  """Raises ValueError unless vmin < vmax and num_atoms is an integer >= 2."""
  if not vmin < vmax or not isinstance(num_atoms, int) or num_atoms < 2:
    raise ValueError(f"need vmin < vmax and an integer num_atoms >= 2, got vmin={vmin}, "
                     f"vmax={vmax}, num_atoms={num_atoms!r}")


def check_concrete_support(vmin, vmax, num_atoms: int) -> None:
  """`check_support` where vmin and vmax are numbers (inside a compiled function, arrays whose
  values the config checked)."""
  if not any(isinstance(v, jax.core.Tracer) for v in (vmin, vmax)):
    check_support(float(vmin), float(vmax), num_atoms)


def atoms(vmin, vmax, num_atoms: int) -> jax.Array:
  """(num_atoms,) evenly spaced support from vmin to vmax (numbers, or arrays inside a
  compiled function, whose values the config checked)."""
  check_concrete_support(vmin, vmax, num_atoms)
  return jnp.linspace(vmin, vmax, num_atoms)


def project(support: jax.Array, probs: jax.Array, reward: jax.Array,
            discount: jax.Array) -> jax.Array:
  """Projects the distribution of reward + discount * Z onto `support`, in O(atoms).

  Z puts `probs` (..., K) on `support` (K,); reward and discount have shape (...). Each shifted
  atom is clipped to [vmin, vmax] and its mass split between the two support atoms around it,
  in proportion to closeness (all of it to one atom when it lands exactly on one).
  Returns (..., K) probabilities.
  """
  vmin, vmax = support[0], support[-1]
  k = support.shape[0]
  delta = (vmax - vmin) / (k - 1)
  shifted = jnp.clip(reward[..., None] + discount[..., None] * support, vmin, vmax)
  position = (shifted - vmin) / delta                      # in [0, K - 1]
  lower = jnp.clip(jnp.floor(position), 0, k - 1)
  upper = jnp.clip(lower + 1, 0, k - 1)
  upper_weight = position - lower                          # 0 when on an atom (or at vmax)
  flat_probs = probs.reshape(-1, k)

  def one(p, lo, up, w):
    out = jnp.zeros(k, p.dtype).at[lo.astype(jnp.int32)].add(p * (1 - w))
    return out.at[up.astype(jnp.int32)].add(p * w)

  out = jax.vmap(one)(flat_probs, lower.reshape(-1, k), upper.reshape(-1, k),
                      upper_weight.reshape(-1, k))
  return out.reshape(probs.shape)


def mean(support: jax.Array, logits: jax.Array) -> jax.Array:
  """(...,) expected value of the categorical distribution with these (..., K) logits."""
  return jnp.sum(jax.nn.softmax(logits) * support, axis=-1)


def cross_entropy(logits: jax.Array, target_probs: jax.Array) -> jax.Array:
  """(...,) cross-entropy of target probabilities against predicted logits."""
  return -jnp.sum(target_probs * jax.nn.log_softmax(logits), axis=-1)
