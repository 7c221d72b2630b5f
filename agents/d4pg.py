"""D4PG: a deterministic policy with a categorical (distributional) critic, n-step returns,
target networks and Gaussian exploration, with acme's JAX learner semantics.

    agent = d4pg.make(obs_size, action_size, d4pg.Config())     # or d4pg.PRESETS["cpu"]
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from mjx_hopper import distributional, networks
from mjx_hopper.agents.base import Agent, pmean


@dataclasses.dataclass(frozen=True)
class Config:
  """Defaults are the seed notebook's networks and acme's D4PG hyperparameters."""

  policy_layers: tuple[int, ...] = (256, 256, 256)
  critic_layers: tuple[int, ...] = (512, 512, 256)
  vmin: float = -150.0
  vmax: float = 150.0
  num_atoms: int = 51
  learning_rate: float = 1e-4
  discount: float = 0.99
  n_step: int = 5
  sigma: float = 0.3                 # std of the Gaussian exploration noise
  target_update_period: int = 100    # updates between copies into the target networks
  max_grad_norm: float = 40.0        # acme's gradient clipping

  def __post_init__(self):
    check_common(self)
    if self.num_atoms < 2 or not self.vmin < self.vmax:
      raise ValueError(f"need num_atoms >= 2 and vmin < vmax, got num_atoms={self.num_atoms}, "
                       f"vmin={self.vmin}, vmax={self.vmax}")


def check_common(cfg) -> None:
  """Errors for the settings every agent shares."""
  if not isinstance(cfg.n_step, int) or cfg.n_step < 1:
    raise ValueError(f"n_step must be an integer >= 1, got {cfg.n_step!r}")
  if not 0.0 <= cfg.discount <= 1.0:
    raise ValueError(f"discount must be in [0, 1], got {cfg.discount}")
  if cfg.learning_rate <= 0:
    raise ValueError(f"learning_rate must be > 0, got {cfg.learning_rate}")
  if cfg.target_update_period < 1:
    raise ValueError(f"target_update_period must be >= 1, got {cfg.target_update_period}")


# "seed": the seed notebook's settings. The others widen the critic's support, since a hopping
# Hopper earns ~2.5 per step, a discounted value of ~250 (> the seed's vmax of 150), and learn
# at 3e-4; "cpu" also halves the networks' depth for a 2-core CPU. BENCHMARKS.md has the runs.
PRESETS = {
    "seed": Config(),
    "gpu": Config(vmin=-150.0, vmax=450.0, learning_rate=3e-4),
    "cpu": Config(policy_layers=(256, 256), critic_layers=(256, 256), vmin=-150.0, vmax=450.0,
                  learning_rate=3e-4),
}


class State(NamedTuple):
  policy: dict
  critic: dict
  target_policy: dict
  target_critic: dict
  policy_opt: optax.OptState
  critic_opt: optax.OptState
  steps: jax.Array  # () int32 updates done


def make(obs_size: int, action_size: int, cfg: Config = Config()) -> Agent:
  policy_net = networks.TanhPolicy(cfg.policy_layers, action_size)
  critic_net = networks.Critic(cfg.critic_layers, cfg.num_atoms)
  support = distributional.atoms(cfg.vmin, cfg.vmax, cfg.num_atoms)
  optimizer = optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm),
                          optax.adam(cfg.learning_rate))

  def init(key):
    policy_key, critic_key = jax.random.split(key)
    obs, action = jnp.zeros((1, obs_size)), jnp.zeros((1, action_size))
    policy = policy_net.init(policy_key, obs)
    critic = critic_net.init(critic_key, obs, action)
    return State(policy, critic, policy, critic, optimizer.init(policy), optimizer.init(critic),
                 jnp.zeros((), jnp.int32))

  def policy(state, obs):
    return policy_net.apply(state.policy, obs)

  def act(state, obs, key):
    action = policy(state, obs)
    return jnp.clip(action + cfg.sigma * jax.random.normal(key, action.shape), -1.0, 1.0)

  def critic_loss(critic_params, state, batch):
    next_action = policy_net.apply(state.target_policy, batch.next_obs)
    next_probs = jax.nn.softmax(critic_net.apply(state.target_critic, batch.next_obs,
                                                 next_action))
    target = distributional.project(support, next_probs, batch.reward, batch.discount)
    logits = critic_net.apply(critic_params, batch.obs, batch.action)
    loss = distributional.cross_entropy(logits, jax.lax.stop_gradient(target)).mean()
    return loss, distributional.mean(support, logits)

  def policy_loss(policy_params, state, batch):
    # As acme's D4PG, the deterministic policy gradient is taken at the next observations.
    action = policy_net.apply(policy_params, batch.next_obs)
    return -distributional.mean(support, critic_net.apply(state.critic, batch.next_obs,
                                                          action)).mean()

  def update(state, batch, key, axis_name=None):
    del key  # D4PG's update is deterministic given the batch
    (c_loss, q), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(state.critic, state,
                                                                        batch)
    p_loss, p_grads = jax.value_and_grad(policy_loss)(state.policy, state, batch)
    c_grads, p_grads = pmean((c_grads, p_grads), axis_name)
    c_updates, critic_opt = optimizer.update(c_grads, state.critic_opt)
    p_updates, policy_opt = optimizer.update(p_grads, state.policy_opt)
    critic = optax.apply_updates(state.critic, c_updates)
    policy_params = optax.apply_updates(state.policy, p_updates)
    steps = state.steps + 1
    copy = steps % cfg.target_update_period == 0
    new = State(policy_params, critic, *update_targets(copy, (policy_params, critic),
                                                       (state.target_policy,
                                                        state.target_critic)),
                policy_opt, critic_opt, steps)
    metrics = {"critic_loss": c_loss, "policy_loss": p_loss, "q_mean": q.mean(),
               "critic_grad_norm": optax.tree.norm(c_grads),
               "policy_grad_norm": optax.tree.norm(p_grads)}
    return new, pmean(metrics, axis_name)

  return Agent(init=init, act=act, policy=policy, update=update, n_step=cfg.n_step,
               discount=cfg.discount)


def update_targets(copy: jax.Array, online, target):
  """The online params where `copy`, else the target params (a periodic hard update)."""
  return jax.tree.map(lambda o, t: jnp.where(copy, o, t), online, target)
