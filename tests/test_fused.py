"""The fused learner (agents/fused.py, pallas_mlp.py) against XLA's, on the CPU in Pallas's
interpret mode: each network's outputs and gradients against its flax module, and D4PG's and
DDPG's whole update (clipped gradients, target copies, the action penalty, two critics, delayed
policy updates, and per-member settings under a sweep's vmap) against the same update on XLA's
path.

Tolerances: float32 agrees to 1e-5 of each array's largest value (the two programs sum the same
products in other orders); bfloat16 to 3e-2 (the fused kernels keep float32 between a layer's
product and its activation, flax rounds to bfloat16 there)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_hopper import replay
from mjx_hopper.agents import d4pg, ddpg, fused, networks, pallas_mlp

OBS, ACT, BATCH = 5, 2, 40  # BATCH is no multiple of the tiles' rows: the kernels pad it
TILES = pallas_mlp.Tiles(rows=32, block=16, num_warps=4, num_stages=2)
TOLERANCE = {"float32": 1e-5, "bfloat16": 3e-2}


def close(a, b, tol):
  """Whether every array of pytree `a` is within tol of `b`'s, relative to b's largest value."""
  def one(x, y):
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    return float(np.abs(x - y).max()) <= tol * max(float(np.abs(y).max()), 1e-6)
  return all(jax.tree.leaves(jax.tree.map(one, a, b)))


def inputs(key):
  k = jax.random.split(key, 2)
  return (jax.random.normal(k[0], (BATCH, OBS)),
          jax.random.uniform(k[1], (BATCH, ACT), minval=-1.2, maxval=1.2))


def perturbed(params, key):
  """Params moved off their initial values, so that biases and LayerNorm are not trivial."""
  leaves, tree = jax.tree.flatten(params)
  keys = jax.random.split(key, len(leaves))
  return tree.unflatten([x + 0.1 * jax.random.normal(k, x.shape) for x, k in zip(leaves, keys)])


NETWORKS = {
    "categorical critic": lambda dtype: networks.Critic((32, 48), 11, dtype),
    "scalar critic": lambda dtype: networks.Critic((32, 16, 16), 1, dtype),
    "policy": lambda dtype: networks.TanhPolicy((16, 32), ACT, dtype),
}


@pytest.mark.parametrize("dtype", ["float32", "bfloat16"])
@pytest.mark.parametrize("kind", list(NETWORKS))
def test_fused_network_matches_flax(kind, dtype):
  net = NETWORKS[kind](jnp.dtype(dtype))
  obs, action = inputs(jax.random.PRNGKey(0))
  if kind == "policy":
    params = perturbed(net.init(jax.random.PRNGKey(1), obs), jax.random.PRNGKey(2))
    flax_apply = lambda p, o, a: net.apply(p, o + a.sum(-1, keepdims=True), squash=False)
    fused_policy = fused.policy(net, TILES, interpret=True)
    fused_apply = lambda p, o, a: fused_policy(p, o + a.sum(-1, keepdims=True))
  else:
    params = perturbed(net.init(jax.random.PRNGKey(1), obs, action), jax.random.PRNGKey(2))
    flax_apply, fused_apply = net.apply, fused.critic(net, TILES, interpret=True)
  out = flax_apply(params, obs, action)
  weights = jax.random.normal(jax.random.PRNGKey(3), out.shape)

  def grads(apply):
    return jax.grad(lambda p, a: jnp.sum(apply(p, obs, a) * weights), argnums=(0, 1))(
        params, action)
  tol = TOLERANCE[dtype]
  assert close(fused_apply(params, obs, action), out, tol)
  assert close(grads(fused_apply), grads(flax_apply), tol)


def random_batch(key, lead=()):
  k = jax.random.split(key, 5)
  return replay.Transition(
      obs=jax.random.normal(k[0], lead + (BATCH, OBS)),
      action=jax.random.uniform(k[1], lead + (BATCH, ACT), minval=-1, maxval=1),
      reward=jax.random.normal(k[2], lead + (BATCH,)) * 3,
      discount=jax.random.choice(k[3], jnp.array([0.0, 0.9, 0.95]), lead + (BATCH,)),
      next_obs=jax.random.normal(k[4], lead + (BATCH, OBS)))


# Small clipping norms and a target copy at every update, so that each part of the update acts.
COMMON = dict(policy_layers=(16, 16), critic_layers=(32, 16), learning_rate=1e-3,
              max_grad_norm=0.5, target_update_period=1, action_penalty=0.1, num_critics=2,
              policy_every=2)
CONFIGS = {"d4pg": (d4pg, d4pg.Config(num_atoms=11, vmin=-10.0, vmax=10.0, **COMMON)),
           "ddpg": (ddpg, ddpg.Config(**COMMON))}


def assert_same_update(xla, fused_):
  """The two paths' new states and metrics agree (float32 tolerance)."""
  (xs, xm), (fs, fm) = xla, fused_
  assert close(fm, xm, TOLERANCE["float32"])
  # Adam's first moments are the clipped gradients scaled; the parameters moved by them.
  assert close((fs.critic_opt, fs.policy_opt), (xs.critic_opt, xs.policy_opt), 1e-4)
  assert close((fs.policy, fs.critic, fs.target_policy, fs.target_critic),
               (xs.policy, xs.critic, xs.target_policy, xs.target_critic), 1e-5)


@pytest.mark.parametrize("name", list(CONFIGS))
def test_fused_update_matches_xla(name):
  module, cfg = CONFIGS[name]
  results = {}
  for learner in ("xla", "fused"):
    agent = module.make(OBS, ACT, cfg, learner=learner)
    update = jax.jit(agent.update)
    state = agent.init(jax.random.PRNGKey(0))
    for i in range(2):  # the policy learns at the first and stands at the second
      state, metrics = update(state, random_batch(jax.random.PRNGKey(i)), jax.random.PRNGKey(i))
      results.setdefault(learner, []).append((state, metrics))
  for xla, fused_ in zip(results["xla"], results["fused"]):
    assert_same_update(xla, fused_)
  assert float(results["fused"][0][1]["policy_loss"]) != 0.0
  assert float(results["fused"][1][1]["policy_loss"]) == 0.0


def test_fused_update_under_a_sweep():
  """Two members with their own settings, vmapped as the trainer's sweeps are."""
  module, cfg = CONFIGS["d4pg"]
  results = {}
  for learner in ("xla", "fused"):
    agent = module.make(OBS, ACT, cfg, learner=learner)
    hps = jax.tree.map(lambda v: jnp.stack([v, v]), agent.hparams)
    hps.update(learning_rate=jnp.array([1e-3, 3e-4]), max_grad_norm=jnp.array([0.5, 40.0]),
               action_penalty=jnp.array([0.1, 0.0]), vmin=jnp.array([-10.0, -5.0]),
               vmax=jnp.array([10.0, 20.0]))
    states = jax.vmap(agent.init)(jax.random.split(jax.random.PRNGKey(0), 2), hps)
    batch = random_batch(jax.random.PRNGKey(1), lead=(2,))
    results[learner] = jax.jit(jax.vmap(agent.update))(states, batch,
                                                       jax.random.split(jax.random.PRNGKey(2)))
  assert_same_update(results["xla"], results["fused"])


def test_learner_path_choice(monkeypatch):
  monkeypatch.delenv(fused.ENV_VAR, raising=False)
  assert fused.path() == "xla" and fused.path("auto") == "xla"
  assert fused.path("fused") == "fused"
  monkeypatch.setenv(fused.ENV_VAR, "fused")
  assert fused.path() == "fused" and fused.path("xla") == "xla"
  monkeypatch.setenv(fused.ENV_VAR, "triton")
  with pytest.raises(ValueError, match="'triton'.*MJX_HOPPER_LEARNER"):
    fused.path()
