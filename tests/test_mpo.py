"""MPO's and DMPO's maths: the E-step and the dual losses against plain NumPy, the decoupled KLs
against the closed-form Gaussian KL, the DMPO target against averaged reference projections,
and duals that stay finite and positive over 1,000 updates on random data."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_hopper import agents
from mjx_hopper.agents import critics, mpo
from mjx_hopper.core import replay
from test_distributional import reference_projection

OBS, ACT = 6, 3


def np_softmax(x, axis):
  e = np.exp(x - x.max(axis=axis, keepdims=True))
  return e / e.sum(axis=axis, keepdims=True)


def test_e_step_matches_numpy():
  rng = np.random.default_rng(0)
  q = rng.normal(0, 30, (20, 64))
  temperature, epsilon = 3.7, 0.1
  weights, loss = mpo.e_step(jnp.asarray(q), jnp.asarray(temperature), epsilon)
  want = np_softmax(q / temperature, axis=0)
  np.testing.assert_allclose(weights, want, rtol=1e-4, atol=1e-7)
  log_mean_exp = np.log(np.mean(np.exp(q / temperature), axis=0))
  assert float(loss) == pytest.approx(temperature * (epsilon + log_mean_exp.mean()), rel=1e-5)
  # The dual's gradient is epsilon minus the KL of the weights from uniform: descending it
  # raises the temperature (flatter weights) when the KL exceeds epsilon, and lowers it below.
  grad = jax.grad(lambda t: mpo.e_step(jnp.asarray(q), t, epsilon)[1])(jnp.asarray(temperature))
  kl = np.sum(want * np.log(want * q.shape[0]), axis=0).mean()
  assert float(grad) == pytest.approx(epsilon - kl, rel=1e-4, abs=1e-6)
  # No gradient reaches the Q-values or flows through the weights.
  assert not np.any(jax.grad(lambda x: mpo.e_step(x, temperature, epsilon)[1])(jnp.asarray(q)))


def test_kl_losses_match_numpy():
  rng = np.random.default_rng(1)
  kl = rng.exponential(1e-3, (64, ACT))
  alpha = rng.uniform(0.1, 5.0, ACT)
  epsilon = 2.5e-3
  penalty, dual, mean_kl = mpo.kl_losses(jnp.asarray(kl), jnp.asarray(alpha), epsilon)
  np.testing.assert_allclose(mean_kl, kl.mean(0), rtol=1e-6)
  assert float(penalty) == pytest.approx(np.sum(alpha * kl.mean(0)), rel=1e-5)
  assert float(dual) == pytest.approx(np.sum(alpha * (epsilon - kl.mean(0))), rel=1e-4)
  # Each term moves only its own variable: the policy's penalty not alpha, the dual not the KL.
  d_penalty = jax.grad(lambda a, k: mpo.kl_losses(k, a, epsilon)[0], argnums=(0, 1))
  d_dual = jax.grad(lambda a, k: mpo.kl_losses(k, a, epsilon)[1], argnums=(0, 1))
  g_alpha, g_kl = d_penalty(jnp.asarray(alpha), jnp.asarray(kl))
  assert not np.any(g_alpha)
  np.testing.assert_allclose(g_kl, np.broadcast_to(alpha / kl.shape[0], kl.shape), rtol=1e-5)
  g_alpha, g_kl = d_dual(jnp.asarray(alpha), jnp.asarray(kl))
  np.testing.assert_allclose(g_alpha, epsilon - kl.mean(0), rtol=1e-4)
  assert not np.any(g_kl)


def closed_form_kl(m0, s0, m1, s1):
  """KL(N(m0, diag s0^2) || N(m1, diag s1^2)) from the general multivariate formula."""
  cov0, cov1 = np.diag(s0 ** 2), np.diag(s1 ** 2)
  inv1 = np.linalg.inv(cov1)
  d = m1 - m0
  return 0.5 * (np.trace(inv1 @ cov0) + d @ inv1 @ d - len(m0)
                + np.log(np.linalg.det(cov1) / np.linalg.det(cov0)))


def test_decoupled_kl_is_the_closed_form_gaussian_kl():
  rng = np.random.default_rng(2)
  tm, om = rng.normal(size=(16, ACT)), rng.normal(size=(16, ACT))
  ts, os_ = rng.uniform(0.05, 2.0, (16, ACT)), rng.uniform(0.05, 2.0, (16, ACT))
  kl_mean, kl_std = mpo.decoupled_kl(*map(jnp.asarray, (tm, ts, om, os_)))
  for b in range(16):
    for a in range(ACT):  # per dimension: one-dimensional Gaussians
      assert float(kl_mean[b, a]) == pytest.approx(
          closed_form_kl(tm[b, [a]], ts[b, [a]], om[b, [a]], ts[b, [a]]), rel=1e-4, abs=1e-7)
      assert float(kl_std[b, a]) == pytest.approx(
          closed_form_kl(tm[b, [a]], ts[b, [a]], tm[b, [a]], os_[b, [a]]), rel=1e-4, abs=1e-7)
    # Summed over dimensions: the multivariate KLs of the decoupled Gaussians.
    assert float(kl_mean[b].sum()) == pytest.approx(closed_form_kl(tm[b], ts[b], om[b], ts[b]),
                                                    rel=1e-4)
    assert float(kl_std[b].sum()) == pytest.approx(closed_form_kl(tm[b], ts[b], tm[b], os_[b]),
                                                   rel=1e-4, abs=1e-7)


def test_gaussian_log_prob_matches_numpy():
  rng = np.random.default_rng(3)
  x, m, s = rng.normal(size=(5, 8, ACT)), rng.normal(size=(8, ACT)), rng.uniform(0.1, 2, (8, ACT))
  want = np.sum(-0.5 * ((x - m) / s) ** 2 - np.log(s * np.sqrt(2 * np.pi)), axis=-1)
  np.testing.assert_allclose(mpo.gaussian_log_prob(x, m, s), want, rtol=1e-5)


def test_dmpo_target_is_the_projection_averaged_over_sampled_actions():
  rng = np.random.default_rng(4)
  support = np.linspace(-10.0, 10.0, 11)
  logits = rng.normal(0, 2, (7, 32, 11))        # 7 sampled actions, 32 states
  reward, discount = rng.uniform(-15, 15, 32), rng.choice([0.0, 0.95], 32)
  got = critics.categorical(-10.0, 10.0, 11).target(jnp.asarray(logits, jnp.float32),
                                                    jnp.asarray(reward, jnp.float32),
                                                    jnp.asarray(discount, jnp.float32))
  probs = np_softmax(logits, axis=-1)
  want = np.mean([reference_projection(support, p, reward, discount) for p in probs], axis=0)
  np.testing.assert_allclose(got, want, atol=2e-5)


def test_scalar_target_averages_over_sampled_actions():
  rng = np.random.default_rng(5)
  q, reward, discount = rng.normal(size=(7, 32)), rng.normal(size=32), rng.uniform(0, 1, 32)
  got = critics.scalar().target(jnp.asarray(q), jnp.asarray(reward), jnp.asarray(discount))
  np.testing.assert_allclose(got, reward + discount * q.mean(0), rtol=1e-5)


SMALL = dict(policy_layers=(16, 16), critic_layers=(32, 16), num_samples=8, learning_rate=1e-3,
             target_update_period=10)
VARIANTS = {
    "mpo": mpo.Config(**SMALL),
    "mpo-squash": mpo.Config(action_bounds="squash", **SMALL),
    "dmpo": mpo.Config(distributional=True, vmin=-10.0, vmax=10.0, num_atoms=11, **SMALL),
}


def random_batch(key, batch):
  k = jax.random.split(key, 5)
  return replay.Transition(
      obs=jax.random.normal(k[0], (batch, OBS)),
      action=jax.random.uniform(k[1], (batch, ACT), minval=-1, maxval=1),
      reward=jax.random.normal(k[2], (batch,)) * 3,
      discount=jax.random.choice(k[3], jnp.array([0.0, 0.99 ** 5]), (batch,)),
      next_obs=jax.random.normal(k[4], (batch, OBS)))


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_duals_stay_finite_and_positive_over_1000_updates(variant):
  agent = mpo.make(OBS, ACT, VARIANTS[variant])

  @jax.jit
  def run(state, key):
    def one(state, key):
      batch_key, update_key = jax.random.split(key)
      state, metrics = agent.update(state, random_batch(batch_key, 32), update_key)
      return state, (jax.tree.map(mpo.positive, state.duals), metrics)
    return jax.lax.scan(one, state, jax.random.split(key, 1000))

  state, (duals, metrics) = run(agent.init(jax.random.PRNGKey(0)), jax.random.PRNGKey(1))
  for name, values in duals._asdict().items():
    values = np.asarray(values)
    assert np.isfinite(values).all() and (values > 0).all(), name
  for name, values in metrics.items():
    assert np.isfinite(np.asarray(values)).all(), name
  jax.tree.map(lambda x: np.testing.assert_array_equal(np.isfinite(x), True), state)
  # The duals moved: the temperature's from its initial raw value of 10.
  assert float(duals.log_temperature[-1]) != pytest.approx(float(mpo.positive(10.0)))


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_actions_are_in_bounds_and_the_policy_is_deterministic(variant):
  agent = mpo.make(OBS, ACT, VARIANTS[variant])
  state = agent.init(jax.random.PRNGKey(0))
  obs = jax.random.normal(jax.random.PRNGKey(1), (4096, OBS))
  explore = agent.act(state, obs, jax.random.PRNGKey(2))
  assert float(jnp.abs(explore).max()) <= 1.0
  assert float(jnp.std(explore - agent.policy(state, obs))) > 0.2  # init std 0.7, squashed
  np.testing.assert_array_equal(agent.policy(state, obs), agent.policy(state, obs))


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_learns_a_bandit_whose_reward_is_the_action_sum(variant):
  """One-step episodes (discount 0) with reward sum(action): the critic learns it, and the
  policy's actions move to the top of their bounds."""
  agent = mpo.make(OBS, ACT, VARIANTS[variant])

  @jax.jit
  def run(state, key):
    def one(state, key):
      batch = random_batch(key, 64)
      batch = batch._replace(reward=batch.action.sum(-1), discount=jnp.zeros(64))
      return agent.update(state, batch, key)[0], None
    return jax.lax.scan(one, state, jax.random.split(key, 1500))[0]

  # acme's initial temperature (softplus(10)) leaves the E-step's weights nearly uniform at
  # first; its dual brings it down over the first thousand updates.
  state = run(agent.init(jax.random.PRNGKey(0)), jax.random.PRNGKey(1))
  obs = jax.random.normal(jax.random.PRNGKey(2), (256, OBS))
  assert float(jnp.mean(agent.policy(state, obs) > 0.9)) > 0.9


def test_dmpo_defaults_are_the_seeds():
  cfg = agents.config("dmpo")
  assert (cfg.distributional, cfg.vmin, cfg.vmax, cfg.num_atoms) == (True, -150.0, 150.0, 51)
  assert (cfg.num_samples, cfg.epsilon, cfg.init_scale, cfg.min_scale) == (20, 0.1, 0.7, 1e-6)
  state = agents.make("dmpo", 15, 3).init(jax.random.PRNGKey(0))
  kernels = sorted(leaf.shape for path, leaf in jax.tree_util.tree_leaves_with_path(state.policy)
                   if path[-1].key == "kernel")
  assert kernels == sorted([(15, 256), (256, 256), (256, 256), (256, 3), (256, 3)])
  mean, std = mpo.networks.GaussianPolicy((256, 256, 256), 3).apply(
      state.policy, jnp.zeros((1, 15)))
  assert mean.shape == std.shape == (1, 3)
  assert not agents.config("mpo").distributional


@pytest.mark.parametrize("bad, message", [
    ({"num_samples": 0}, "num_samples must be an integer >= 1, got 0"),
    ({"epsilon": 0.0}, "epsilon must be > 0, got 0.0"),
    ({"action_bounds": "clip"}, r"action_bounds must be one of \['penalize', 'squash'\], "
                                r"got 'clip'"),
    ({"vmax": -200.0}, "need vmin < vmax"),
])
def test_bad_config(bad, message):
  with pytest.raises(ValueError, match=message):
    agents.config("dmpo", **bad)
