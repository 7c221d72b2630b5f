"""The categorical projection against the slow, obviously-correct K x K reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_hopper.agents import distributional


def reference_projection(support, probs, reward, discount):
  """Each shifted atom, clipped to [vmin, vmax], gives each support atom z_i the share
  max(0, 1 - |shifted - z_i| / delta) of its probability (a triangle kernel): O(K^2)."""
  support = np.asarray(support, np.float64)
  delta = support[1] - support[0]
  out = np.zeros_like(np.asarray(probs, np.float64))
  for b in range(probs.shape[0]):
    for j, z in enumerate(support):
      shifted = np.clip(reward[b] + discount[b] * z, support[0], support[-1])
      for i, zi in enumerate(support):
        out[b, i] += probs[b, j] * max(0.0, 1.0 - abs(shifted - zi) / delta)
  return out


@pytest.mark.parametrize("num_atoms", [2, 11, 51])
def test_projection_matches_reference(num_atoms):
  rng = np.random.default_rng(num_atoms)
  support = np.linspace(-10.0, 10.0, num_atoms)
  batch = 64
  probs = rng.dirichlet(np.ones(num_atoms), batch)
  reward = rng.uniform(-25, 25, batch)          # many shifted atoms fall outside [vmin, vmax]
  discount = rng.choice([0.0, 0.5, 0.99, 1.0], batch) * rng.uniform(0.5, 1.0, batch)
  discount[:8] = 0.0                            # a termination: all mass on clip(reward)
  reward[:4] = np.array([-10.0, 10.0, 0.0, support[1]])  # exactly on atoms and edges
  got = distributional.project(jnp.asarray(support, jnp.float32), jnp.asarray(probs, jnp.float32),
                               jnp.asarray(reward, jnp.float32),
                               jnp.asarray(discount, jnp.float32))
  want = reference_projection(support, probs, reward, discount)
  np.testing.assert_allclose(got, want, atol=2e-5)
  np.testing.assert_allclose(np.asarray(got).sum(-1), 1.0, atol=1e-5)


def test_projection_keeps_leading_shape_and_the_mean_inside_the_support():
  support = distributional.atoms(-5.0, 5.0, 21)
  probs = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(0), (3, 4, 21)))
  reward, discount = jnp.full((3, 4), 0.3), jnp.full((3, 4), 0.9)  # stays within [-5, 5]
  out = distributional.project(support, probs, reward, discount)
  assert out.shape == (3, 4, 21)
  # No clipping happens here, so the projection keeps the mean: E[r + d Z].
  want = 0.3 + 0.9 * jnp.sum(probs * support, -1)
  np.testing.assert_allclose(jnp.sum(out * support, -1), want, atol=1e-4)


def test_cross_entropy_and_mean():
  logits = jnp.log(jnp.array([[0.25, 0.25, 0.5]]))
  target = jnp.array([[0.0, 1.0, 0.0]])
  np.testing.assert_allclose(distributional.cross_entropy(logits, target), [np.log(4.0)],
                             rtol=1e-6)
  np.testing.assert_allclose(distributional.mean(jnp.array([-1.0, 0.0, 2.0]), logits), [0.75],
                             rtol=1e-6)


def test_bad_support():
  with pytest.raises(ValueError,
                     match="vmin < vmax and an integer num_atoms >= 2, got vmin=1.0, vmax=1.0"):
    distributional.atoms(1.0, 1.0, 51)
