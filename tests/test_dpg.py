"""D4PG's and DDPG's maths: each critic loss against a slow reference (with one critic and with
clipped double Q), the policy loss with its action penalty, target updates, the policy
gradient's sign, exploration (one std, and mixed over envs), determinism, the seed's networks,
and config errors."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_hopper import agents
from mjx_hopper.agents import networks
from mjx_hopper.agents import d4pg, ddpg
from mjx_hopper.core import replay
from test_distributional import reference_projection

OBS, ACT, BATCH = 5, 2, 32
COMMON = dict(policy_layers=(16, 16), critic_layers=(32, 16), learning_rate=1e-3,
              target_update_period=3)
SMALL = {"d4pg": d4pg.Config(num_atoms=11, vmin=-10.0, vmax=10.0, **COMMON),
         "ddpg": ddpg.Config(**COMMON)}


def random_batch(key, batch=BATCH):
  k = jax.random.split(key, 5)
  return replay.Transition(
      obs=jax.random.normal(k[0], (batch, OBS)),
      action=jax.random.uniform(k[1], (batch, ACT), minval=-1, maxval=1),
      reward=jax.random.normal(k[2], (batch,)) * 3,
      discount=jax.random.choice(k[3], jnp.array([0.0, 0.9, 0.99 ** 5]), (batch,)),
      next_obs=jax.random.normal(k[4], (batch, OBS)))


@pytest.fixture(scope="module", params=["d4pg", "ddpg"])
def name(request):
  return request.param


@pytest.fixture(scope="module")
def agent(name):
  return agents.make(name, OBS, ACT, SMALL[name])


@pytest.fixture(scope="module")
def update(agent):
  return jax.jit(agent.update)


def critic_net(name):
  cfg = SMALL[name]
  return networks.Critic(cfg.critic_layers, cfg.num_atoms if name == "d4pg" else 1)


def reference_critic_loss(name, state, batch):
  """The TD loss and mean Q in float64 NumPy, from the networks' raw outputs."""
  cfg, net = SMALL[name], critic_net(name)
  policy_net = networks.TanhPolicy(cfg.policy_layers, ACT)
  next_out = np.asarray(net.apply(state.target_critic, batch.next_obs,
                                  policy_net.apply(state.target_policy, batch.next_obs)),
                        np.float64)
  out = np.asarray(net.apply(state.critic, batch.obs, batch.action), np.float64)
  reward, discount = np.asarray(batch.reward), np.asarray(batch.discount)
  if name == "ddpg":
    return np.mean(0.5 * (out - (reward + discount * next_out)) ** 2), out.mean()
  support = np.linspace(cfg.vmin, cfg.vmax, cfg.num_atoms)
  next_probs = np.exp(next_out) / np.exp(next_out).sum(-1, keepdims=True)
  target = reference_projection(support, next_probs, reward, discount)
  log_probs = out - np.log(np.exp(out).sum(-1, keepdims=True))
  return -(target * log_probs).sum(-1).mean(), (np.exp(log_probs) * support).sum(-1).mean()


def test_critic_loss_matches_reference(name, agent, update):
  state = agent.init(jax.random.PRNGKey(0))
  batch = random_batch(jax.random.PRNGKey(1))
  _, metrics = update(state, batch, jax.random.PRNGKey(2))
  loss, q = reference_critic_loss(name, state, batch)
  assert float(metrics["critic_loss"]) == pytest.approx(loss, rel=1e-4)
  assert float(metrics["q_mean"]) == pytest.approx(q, rel=1e-4, abs=1e-5)


def test_clipped_double_q_matches_reference(name):
  """With two critics, each fits the target of the critic whose next value is lowest, and the
  policy loss is minus the lowest value at the next observations."""
  cfg = dataclasses.replace(SMALL[name], num_critics=2)
  agent = agents.make(name, OBS, ACT, cfg)
  state = agent.init(jax.random.PRNGKey(0))
  # Different target critics, so that the lowest one differs from sample to sample.
  state = state._replace(target_critic=jax.tree.map(
      lambda x: x * jnp.array([1.0, -0.7]).reshape((2,) + (1,) * (x.ndim - 1)),
      state.target_critic))
  batch = random_batch(jax.random.PRNGKey(1))
  _, metrics = jax.jit(agent.update)(state, batch, jax.random.PRNGKey(2))

  net = critic_net(name)
  support = np.linspace(cfg.vmin, cfg.vmax, cfg.num_atoms) if name == "d4pg" else None
  policy_net = networks.TanhPolicy(cfg.policy_layers, ACT)
  critic = lambda params, k, obs, action: np.asarray(
      net.apply(jax.tree.map(lambda x: x[k], params), obs, action), np.float64)

  def value(out):
    if name == "ddpg":
      return out
    probs = np.exp(out) / np.exp(out).sum(-1, keepdims=True)
    return (probs * support).sum(-1)
  next_action = policy_net.apply(state.target_policy, batch.next_obs)
  next_out = [critic(state.target_critic, k, batch.next_obs, next_action) for k in range(2)]
  pick = value(next_out[1]) < value(next_out[0])
  assert 0 < pick.sum() < BATCH  # both critics are picked somewhere
  chosen = np.where(pick.reshape((-1,) + (1,) * (next_out[0].ndim - 1)), next_out[1], next_out[0])
  reward, discount = np.asarray(batch.reward), np.asarray(batch.discount)
  loss = 0.0
  for k in range(2):
    out = critic(state.critic, k, batch.obs, batch.action)
    if name == "ddpg":
      loss += np.mean(0.5 * (out - (reward + discount * chosen)) ** 2)
    else:
      probs = np.exp(chosen) / np.exp(chosen).sum(-1, keepdims=True)
      target = reference_projection(support, probs, reward, discount)
      loss += -(target * (out - np.log(np.exp(out).sum(-1, keepdims=True)))).sum(-1).mean()
  assert float(metrics["critic_loss"]) == pytest.approx(loss, rel=1e-4)
  action = policy_net.apply(state.policy, batch.next_obs)
  lowest = np.minimum(*[value(critic(state.critic, k, batch.next_obs, action)) for k in range(2)])
  assert float(metrics["policy_loss"]) == pytest.approx(-lowest.mean(), rel=1e-4, abs=1e-5)


def penalised_state(name, agent, key, penalty, scale):
  """A fresh state with this action penalty (a dynamic setting: the compiled update serves
  every value), its policy's last layer (weights and bias) multiplied by `scale`."""
  state = agent.init(key, {**agent.hparams, "action_penalty": jnp.float32(penalty)})
  last = f"Dense_{len(SMALL[name].policy_layers)}"
  return state._replace(policy=jax.tree_util.tree_map_with_path(
      lambda path, x: x * scale if last in jax.tree_util.keystr(path) else x, state.policy))


@pytest.mark.parametrize("penalty", [0.0, 0.3])
def test_policy_loss_and_saturation_match_reference(name, agent, update, penalty):
  """The policy loss is minus the critic's value of the policy's actions at the next
  observations, plus action_penalty times the mean squared pre-tanh action; policy_saturated is
  the fraction of pre-tanh actions beyond +-3."""
  cfg = SMALL[name]
  # Some of its actions saturate and some do not.
  state = penalised_state(name, agent, jax.random.PRNGKey(5), penalty, 15.0)
  batch = random_batch(jax.random.PRNGKey(6), batch=256)
  _, metrics = update(state, batch, jax.random.PRNGKey(0))

  policy_net = networks.TanhPolicy(cfg.policy_layers, ACT)
  pre = np.asarray(policy_net.apply(state.policy, batch.next_obs, squash=False), np.float64)
  out = np.asarray(critic_net(name).apply(state.critic, batch.next_obs, np.tanh(pre)), np.float64)
  if name == "d4pg":
    probs = np.exp(out) / np.exp(out).sum(-1, keepdims=True)
    out = (probs * np.linspace(cfg.vmin, cfg.vmax, cfg.num_atoms)).sum(-1)
  saturated = np.mean(np.abs(pre) > 3.0)
  assert 0.05 < saturated < 0.95
  assert float(metrics["policy_saturated"]) == pytest.approx(saturated, abs=1e-6)
  want = -out.mean() + penalty * np.mean(pre ** 2)
  assert float(metrics["policy_loss"]) == pytest.approx(want, rel=1e-4, abs=1e-5)


def test_action_penalty_pulls_a_saturated_policy_back(name, agent, update):
  """From a policy whose tanh is pinned at +-1, updates with a penalty bring its pre-tanh
  actions back inside +-3, where the critic's gradient reaches it again; without one they
  stay pinned."""
  batch = random_batch(jax.random.PRNGKey(7), batch=256)
  saturated = {}
  for penalty in (0.0, 1.0):
    state = penalised_state(name, agent, jax.random.PRNGKey(8), penalty, 30.0)
    for i in range(300):
      state, metrics = update(state, batch, jax.random.PRNGKey(i))
    saturated[penalty] = float(metrics["policy_saturated"])
  assert saturated[0.0] > 0.5
  assert saturated[1.0] < 0.1


def test_delayed_policy_updates(name, agent, update):
  """With policy_every=3 the critic learns at every update, as with 1, and the policy only at
  updates 0, 3, 6, ...: there as with 1, its metrics 3 times its own; elsewhere 0, and the
  policy and its optimizer state are left as they were."""
  delayed = jax.jit(agents.make(name, OBS, ACT,
                                dataclasses.replace(SMALL[name], policy_every=3)).update)
  state = agent.init(jax.random.PRNGKey(11))
  policy_metrics = ("policy_loss", "policy_grad_norm", "policy_saturated")
  for step in range(4):
    batch = random_batch(jax.random.PRNGKey(20 + step))
    every, every_metrics = update(state, batch, jax.random.PRNGKey(0))
    new, metrics = delayed(state, batch, jax.random.PRNGKey(0))
    # (Two programs compiled apart: equal to a tolerance, not bit for bit.)
    close = functools.partial(np.testing.assert_allclose, rtol=1e-5, atol=1e-7)
    jax.tree.map(close, (new.critic, new.critic_opt, new.steps),
                 (every.critic, every.critic_opt, every.steps))
    assert float(metrics["critic_loss"]) == pytest.approx(float(every_metrics["critic_loss"]),
                                                          rel=1e-5)
    if step % 3 == 0:
      jax.tree.map(close, (new.policy, new.policy_opt), (every.policy, every.policy_opt))
      for key in policy_metrics:
        assert float(metrics[key]) == pytest.approx(3 * float(every_metrics[key]), rel=1e-6)
      assert float(every_metrics["policy_grad_norm"]) > 0
    else:
      jax.tree.map(np.testing.assert_array_equal, (new.policy, new.policy_opt),
                   (state.policy, state.policy_opt))
      assert all(float(metrics[key]) == 0 for key in policy_metrics)
    state = new


def test_mixed_noise_spreads_sigma_over_envs(name):
  """With sigma_min, env i of n explores at sigma_min + (sigma - sigma_min) * i / (n - 1)."""
  cfg = dataclasses.replace(SMALL[name], sigma=0.4, sigma_min=0.05)
  agent = agents.make(name, OBS, ACT, cfg)
  state = agent.init(jax.random.PRNGKey(0))
  obs = jnp.zeros((5, OBS))
  keys = jax.random.split(jax.random.PRNGKey(1), 4000)
  actions = jax.vmap(lambda k: agent.act(state, obs, k))(keys)     # (4000, 5, ACT)
  assert float(jnp.abs(agent.policy(state, obs)).max()) < 0.3      # clipping rarely bites
  std = np.asarray(jnp.std(actions - agent.policy(state, obs), axis=(0, 2)))
  np.testing.assert_allclose(std, np.linspace(0.05, 0.4, 5), rtol=0.06)


def test_targets_are_copied_every_period(name, agent, update):
  state = agent.init(jax.random.PRNGKey(0))
  initial = (state.target_policy, state.target_critic)
  for i in range(1, 7):
    state, _ = update(state, random_batch(jax.random.PRNGKey(i)), jax.random.PRNGKey(0))
    targets = (state.target_policy, state.target_critic)
    if i % SMALL[name].target_update_period == 0:
      jax.tree.map(np.testing.assert_array_equal, targets, (state.policy, state.critic))
      initial = targets
    else:
      jax.tree.map(np.testing.assert_array_equal, targets, initial)
      assert not np.array_equal(state.policy["params"]["LayerNormMLP_0"]["Dense_0"]["kernel"],
                                targets[0]["params"]["LayerNormMLP_0"]["Dense_0"]["kernel"])


def test_policy_step_raises_q_under_the_critic(name, agent, update):
  state = agent.init(jax.random.PRNGKey(3))
  batch = random_batch(jax.random.PRNGKey(4), batch=256)
  new, _ = update(state, batch, jax.random.PRNGKey(0))
  net = critic_net(name)
  cfg = SMALL[name]

  def q(policy_state):  # under the critic the step was taken against
    out = net.apply(state.critic, batch.next_obs, agent.policy(policy_state, batch.next_obs))
    if name == "ddpg":
      return float(out.mean())
    return float(jnp.mean(jax.nn.softmax(out) @ jnp.linspace(cfg.vmin, cfg.vmax, cfg.num_atoms)))
  assert q(new) > q(state)


def test_exploration_is_noisy_and_bounded(name, agent):
  state = agent.init(jax.random.PRNGKey(0))
  obs = jax.random.normal(jax.random.PRNGKey(1), (4096, OBS))
  noise = agent.act(state, obs, jax.random.PRNGKey(2)) - agent.policy(state, obs)
  assert float(jnp.abs(agent.act(state, obs, jax.random.PRNGKey(2))).max()) <= 1.0
  inside = jnp.abs(agent.policy(state, obs)) < 0.5  # where clipping rarely bites
  assert float(jnp.std(noise[inside])) == pytest.approx(SMALL[name].sigma, rel=0.05)


def test_same_seed_same_params(agent, update):
  def run(seed):
    state = agent.init(jax.random.PRNGKey(seed))
    for i in range(3):
      state, _ = update(state, random_batch(jax.random.PRNGKey(10 + i)), jax.random.PRNGKey(i))
    return state
  jax.tree.map(np.testing.assert_array_equal, run(0), run(0))
  assert not np.array_equal(run(0).policy["params"]["LayerNormMLP_0"]["Dense_0"]["kernel"],
                            run(1).policy["params"]["LayerNormMLP_0"]["Dense_0"]["kernel"])


def kernels(params):
  return sorted(leaf.shape for path, leaf in jax.tree_util.tree_leaves_with_path(params)
                if path[-1].key == "kernel")


@pytest.mark.parametrize("name, head", [("d4pg", 51), ("ddpg", 1)])
def test_default_networks_are_the_seeds(name, head):
  state = agents.make(name, 15, 3).init(jax.random.PRNGKey(0))
  assert kernels(state.policy) == sorted([(15, 256), (256, 256), (256, 256), (256, 3)])
  assert kernels(state.critic) == sorted([(18, 512), (512, 512), (512, 256), (256, head)])


@pytest.mark.parametrize("net, inputs", [
    (networks.TanhPolicy((64, 64), ACT), 1),
    (networks.Critic((64, 64), 11), 2),
    (networks.Critic((64, 64), 1), 2),
    (networks.GaussianPolicy((64, 64), ACT), 1),
])
def test_bfloat16_networks_track_float32(net, inputs):
  """The same parameters give float32 outputs within bfloat16's rounding of float32's, so a
  state trains, saves and loads alike in either dtype."""
  k = jax.random.split(jax.random.PRNGKey(3), 3)
  args = (jax.random.normal(k[0], (256, OBS)), jax.random.uniform(k[1], (256, ACT), minval=-1))
  args = args[:inputs]
  params = net.init(k[2], *args)
  half = net.clone(dtype=jnp.bfloat16)
  assert jax.tree.structure(half.init(k[2], *args)) == jax.tree.structure(params)
  for full, low in zip(jax.tree.leaves(net.apply(params, *args)),
                       jax.tree.leaves(half.apply(params, *args))):
    assert low.dtype == jnp.float32
    scale = float(jnp.abs(full).max())
    assert 1e-4 * scale < float(jnp.abs(low - full).max()) < 0.05 * scale  # bf16, not f32


def test_bfloat16_update_tracks_float32(name, agent, update):
  low = agents.make(name, OBS, ACT, dataclasses.replace(SMALL[name], compute_dtype="bfloat16"))
  state = agent.init(jax.random.PRNGKey(4))
  batch = random_batch(jax.random.PRNGKey(5))
  full_state, full = update(state, batch, None)
  low_state, low_metrics = jax.jit(low.update)(state, batch, None)
  for key in ("critic_loss", "policy_loss", "q_mean", "critic_grad_norm", "policy_grad_norm"):
    assert float(low_metrics[key]) == pytest.approx(float(full[key]), rel=0.02, abs=2e-3)
  assert jax.tree.map(lambda x: x.dtype, low_state) == jax.tree.map(lambda x: x.dtype, full_state)


@pytest.mark.parametrize("name", ["d4pg", "ddpg", "mpo", "dmpo"])
@pytest.mark.parametrize("bad, message", [
    ({"n_step": 0}, "n_step must be an integer >= 1, got 0"),
    ({"discount": 1.5}, r"discount must be in \[0, 1\], got 1.5"),
    ({"learning_rate": 0.0}, "learning_rate must be > 0, got 0.0"),
    ({"critic_layers": ()}, r"critic_layers must be a non-empty tuple of positive integers"),
    ({"compute_dtype": "float16"},
     r"compute_dtype must be one of \['float32', 'bfloat16'\], got 'float16'"),
])
def test_bad_common_config(name, bad, message):
  with pytest.raises(ValueError, match=message):
    agents.config(name, **bad)


@pytest.mark.parametrize("name, bad, message", [
    ("d4pg", {"num_atoms": 1}, "need vmin < vmax and an integer num_atoms >= 2"),
    ("d4pg", {"vmin": 5.0, "vmax": 5.0}, "need vmin < vmax"),
    ("ddpg", {"sigma": -0.1}, "sigma must be >= 0, got -0.1"),
    ("d4pg", {"sigma_min": 0.5}, r"sigma_min must be None or in \[0, sigma=0.3\], got 0.5"),
    ("ddpg", {"num_critics": 0}, "num_critics must be an integer >= 1, got 0"),
    ("d4pg", {"action_penalty": -0.1}, "action_penalty must be >= 0, got -0.1"),
    ("ddpg", {"policy_every": 0}, "policy_every must be an integer >= 1, got 0"),
])
def test_bad_agent_config(name, bad, message):
  with pytest.raises(ValueError, match=message):
    agents.config(name, **bad)


def test_unknown_agent_and_settings():
  with pytest.raises(ValueError, match=r"unknown agent 'd5pg'; valid agents are "
                                       r"\['d4pg', 'ddpg', 'dmpo', 'mpo'\]"):
    agents.config("d5pg")
  with pytest.raises(ValueError, match=r"unknown d4pg settings \['sgima'\]"):
    agents.config("d4pg", sgima=0.2)
  with pytest.raises(ValueError, match=r"unknown defaults 'gpu2' for d4pg; valid defaults are "
                     r"\['acme', 'cpu', 'gpu'\]"):
    agents.config("d4pg", defaults="gpu2")


def reference_critic(params: dict, obs, action, norm_every: bool) -> np.ndarray:
  """The critic's logits in plain NumPy: Dense, LayerNorm, tanh; then Dense, (LayerNorm with
  `norm_every`), ELU for each other hidden layer; then the output Dense."""
  def layer_norm(x, p):
    mean, var = x.mean(-1, keepdims=True), x.var(-1, keepdims=True)
    return (x - mean) / np.sqrt(var + 1e-6) * p["scale"] + p["bias"]

  def dense(x, p):
    return x @ np.asarray(p["kernel"], np.float64) + np.asarray(p["bias"], np.float64)
  mlp = jax.tree.map(lambda a: np.asarray(a, np.float64), params["params"]["LayerNormMLP_0"])
  x = np.concatenate([obs, np.clip(action, -1, 1)], -1).astype(np.float64)
  x = np.tanh(layer_norm(dense(x, mlp["Dense_0"]), mlp["LayerNorm_0"]))
  for i in range(1, len([k for k in mlp if k.startswith("Dense")])):
    x = dense(x, mlp[f"Dense_{i}"])
    x = layer_norm(x, mlp[f"LayerNorm_{i}"]) if norm_every else x
    x = np.where(x > 0, x, np.expm1(np.minimum(x, 0)))
  return dense(x, params["params"]["Dense_0"])


@pytest.mark.parametrize("norm_every", [False, True])
def test_critic_norm_puts_a_layer_norm_after_every_hidden_layer(norm_every):
  """acme's critic normalises its first layer's output; with critic_norm, every hidden layer's
  (D4PG's critic against a NumPy forward pass on random inputs)."""
  cfg = dataclasses.replace(SMALL["d4pg"], critic_layers=(32, 16, 8), critic_norm=norm_every)
  state = agents.make("d4pg", OBS, ACT, cfg).init(jax.random.PRNGKey(6))
  norms = [k for k in state.critic["params"]["LayerNormMLP_0"] if k.startswith("LayerNorm")]
  assert len(norms) == (3 if norm_every else 1)
  net = networks.Critic(cfg.critic_layers, cfg.num_atoms, norm_every=norm_every)
  k = jax.random.split(jax.random.PRNGKey(7))
  obs, action = jax.random.normal(k[0], (64, OBS)), jax.random.uniform(k[1], (64, ACT), minval=-2)
  np.testing.assert_allclose(net.apply(state.critic, obs, action),
                             reference_critic(state.critic, np.asarray(obs), np.asarray(action),
                                              norm_every), rtol=1e-4, atol=1e-4)
