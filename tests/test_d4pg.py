"""D4PG's maths: the critic loss against a slow reference, target updates, the policy gradient's
sign, determinism, and its config errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_hopper import agents, networks, replay
from mjx_hopper.agents import d4pg
from test_distributional import reference_projection

OBS, ACT, BATCH = 5, 2, 32
SMALL = d4pg.Config(policy_layers=(16, 16), critic_layers=(32, 16), num_atoms=11, vmin=-10.0,
                    vmax=10.0, learning_rate=1e-3, target_update_period=3)


def random_batch(key, batch=BATCH):
  k = jax.random.split(key, 5)
  return replay.Transition(
      obs=jax.random.normal(k[0], (batch, OBS)),
      action=jax.random.uniform(k[1], (batch, ACT), minval=-1, maxval=1),
      reward=jax.random.normal(k[2], (batch,)) * 3,
      discount=jax.random.choice(k[3], jnp.array([0.0, 0.9, 0.99 ** 5]), (batch,)),
      next_obs=jax.random.normal(k[4], (batch, OBS)))


@pytest.fixture(scope="module")
def agent():
  return d4pg.make(OBS, ACT, SMALL)


@pytest.fixture(scope="module")
def update(agent):
  return jax.jit(agent.update)


def test_critic_loss_matches_reference(agent, update):
  state = agent.init(jax.random.PRNGKey(0))
  batch = random_batch(jax.random.PRNGKey(1))
  _, metrics = update(state, batch, jax.random.PRNGKey(2))
  policy_net = networks.TanhPolicy(SMALL.policy_layers, ACT)
  critic_net = networks.Critic(SMALL.critic_layers, SMALL.num_atoms)
  support = np.linspace(SMALL.vmin, SMALL.vmax, SMALL.num_atoms)
  next_action = policy_net.apply(state.target_policy, batch.next_obs)
  next_probs = np.asarray(jax.nn.softmax(critic_net.apply(state.target_critic, batch.next_obs,
                                                          next_action)), np.float64)
  target = reference_projection(support, next_probs, np.asarray(batch.reward),
                                np.asarray(batch.discount))
  logits = np.asarray(critic_net.apply(state.critic, batch.obs, batch.action), np.float64)
  log_probs = logits - np.log(np.exp(logits).sum(-1, keepdims=True))
  want = -(target * log_probs).sum(-1).mean()
  assert float(metrics["critic_loss"]) == pytest.approx(want, rel=1e-4)
  q = (np.exp(log_probs) * support).sum(-1).mean()
  assert float(metrics["q_mean"]) == pytest.approx(q, rel=1e-4, abs=1e-5)


def test_targets_are_copied_every_period(agent, update):
  state = agent.init(jax.random.PRNGKey(0))
  initial = (state.target_policy, state.target_critic)
  for i in range(1, 7):
    state, _ = update(state, random_batch(jax.random.PRNGKey(i)), jax.random.PRNGKey(0))
    targets = (state.target_policy, state.target_critic)
    if i % SMALL.target_update_period == 0:
      jax.tree.map(np.testing.assert_array_equal, targets, (state.policy, state.critic))
      initial = targets
    else:
      jax.tree.map(np.testing.assert_array_equal, targets, initial)
      assert not np.array_equal(state.policy["params"]["LayerNormMLP_0"]["Dense_0"]["kernel"],
                                targets[0]["params"]["LayerNormMLP_0"]["Dense_0"]["kernel"])


def test_policy_step_raises_q_under_the_critic(agent, update):
  state = agent.init(jax.random.PRNGKey(3))
  batch = random_batch(jax.random.PRNGKey(4), batch=256)
  new, _ = update(state, batch, jax.random.PRNGKey(0))
  critic_net = networks.Critic(SMALL.critic_layers, SMALL.num_atoms)
  support = jnp.linspace(SMALL.vmin, SMALL.vmax, SMALL.num_atoms)

  def q(policy_state):  # under the critic the step was taken against
    action = agent.policy(policy_state, batch.next_obs)
    return float(jnp.mean(jax.nn.softmax(critic_net.apply(state.critic, batch.next_obs, action))
                          @ support))
  assert q(new) > q(state)


def test_exploration_is_noisy_and_bounded(agent):
  state = agent.init(jax.random.PRNGKey(0))
  obs = jax.random.normal(jax.random.PRNGKey(1), (4096, OBS))
  noise = agent.act(state, obs, jax.random.PRNGKey(2)) - agent.policy(state, obs)
  assert float(jnp.abs(agent.act(state, obs, jax.random.PRNGKey(2))).max()) <= 1.0
  inside = jnp.abs(agent.policy(state, obs)) < 0.5  # where clipping rarely bites
  assert float(jnp.std(noise[inside])) == pytest.approx(SMALL.sigma, rel=0.05)


def test_same_seed_same_params(agent, update):
  def run(seed):
    state = agent.init(jax.random.PRNGKey(seed))
    for i in range(3):
      state, _ = update(state, random_batch(jax.random.PRNGKey(10 + i)), jax.random.PRNGKey(i))
    return state
  jax.tree.map(np.testing.assert_array_equal, run(0), run(0))
  assert not np.array_equal(run(0).policy["params"]["LayerNormMLP_0"]["Dense_0"]["kernel"],
                            run(1).policy["params"]["LayerNormMLP_0"]["Dense_0"]["kernel"])


def test_default_networks_are_the_seeds():
  agent = agents.make("d4pg", 15, 3)
  state = agent.init(jax.random.PRNGKey(0))
  def kernels(params):
    return sorted(leaf.shape for path, leaf in jax.tree_util.tree_leaves_with_path(params)
                  if path[-1].key == "kernel")
  assert kernels(state.policy) == sorted([(15, 256), (256, 256), (256, 256), (256, 3)])
  assert kernels(state.critic) == sorted([(18, 512), (512, 512), (512, 256), (256, 51)])


@pytest.mark.parametrize("bad, message", [
    ({"n_step": 0}, "n_step must be an integer >= 1, got 0"),
    ({"discount": 1.5}, r"discount must be in \[0, 1\], got 1.5"),
    ({"num_atoms": 1}, "need num_atoms >= 2"),
])
def test_bad_config(bad, message):
  with pytest.raises(ValueError, match=message):
    agents.config("d4pg", **bad)


def test_unknown_agent_and_settings():
  with pytest.raises(ValueError, match=r"unknown agent 'd5pg'; valid agents are \['d4pg'"):
    agents.config("d5pg")
  with pytest.raises(ValueError, match=r"unknown d4pg settings \['sgima'\]"):
    agents.config("d4pg", sgima=0.2)
  with pytest.raises(ValueError, match=r"unknown preset 'gpu2' for d4pg"):
    agents.config("d4pg", preset="gpu2")
