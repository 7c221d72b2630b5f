"""Deterministic policy-gradient agents (DDPG and D4PG): a tanh policy, a critic with a scalar or
categorical head, n-step TD targets from target networks, Gaussian exploration, with acme's
learner semantics. `ddpg.py` and `d4pg.py` choose the head and the defaults.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import optax

from mjx_hopper.agents import base, critics, networks
from mjx_hopper.agents.base import (COMPUTE_DTYPES, Agent, CommonConfig, optimizer, pmean,
                                    update_targets)


# |pre-tanh action| above which the tanh's slope is below 0.01: the "policy_saturated" metric is
# the fraction of a batch's actions past it.
_SATURATED = 3.0


@dataclasses.dataclass(frozen=True)
class Config(CommonConfig):
  """DDPG's and D4PG's settings beyond the common ones: exploration, the critics, and TD3's
  tricks (clipped double Q, delayed policy updates), each off by default as in acme."""

  DYNAMIC: ClassVar[tuple[str, ...]] = CommonConfig.DYNAMIC + ("sigma", "action_penalty")

  sigma: float = 0.3                 # std of the Gaussian exploration noise
  # Mixed exploration noise (FastTD3's): env i of n explores at std sigma_min + (sigma -
  # sigma_min) * i / (n - 1), so that some envs act near the greedy policy and others explore
  # widely. None: every env at sigma.
  sigma_min: float | None = None
  # Critics trained side by side. With 2 or more, clipped double Q (TD3's): each fits the TD
  # target of the critic whose next-state value is lowest, and the policy ascends the lowest
  # value, which curbs the overestimation that a deterministic policy exploits.
  num_critics: int = 1
  # Weight of the mean squared pre-tanh action in the policy loss. It keeps the policy out of
  # the tanh's flat tails, where an early overestimating critic can pin it: there the policy
  # gradient vanishes while Adam still remembers the large first gradients. 0: acme's loss.
  action_penalty: float = 0.0
  # Updates per policy update (TD3's delayed policy updates): the critic learns at every update,
  # the policy at one update in `policy_every`. 1: acme's learner. A single run skips the other
  # updates' policy gradients; in a sweep (members under vmap) both branches run, so it saves
  # nothing there. The policy's metrics are `policy_every` times its update's figures, and 0 at
  # the other updates, so that the trainer's mean over an iteration's updates is the mean over
  # those that learned the policy (exactly where policy_every divides the updates per iteration).
  policy_every: int = 1
  # LayerNorm after every hidden layer of the critics (FastSAC's), not after the first alone
  # (acme's LayerNormMLP): it keeps the critic's features at one scale under many updates.
  critic_norm: bool = False

  def __post_init__(self):
    super().__post_init__()
    if not self.sigma >= 0:
      raise ValueError(f"sigma must be >= 0, got {self.sigma}")
    if self.sigma_min is not None and not 0 <= self.sigma_min <= self.sigma:
      raise ValueError(f"sigma_min must be None or in [0, sigma={self.sigma}], got "
                       f"{self.sigma_min}")
    if not self.action_penalty >= 0:
      raise ValueError(f"action_penalty must be >= 0, got {self.action_penalty}")
    if not isinstance(self.policy_every, int) or self.policy_every < 1:
      raise ValueError(f"policy_every must be an integer >= 1, got {self.policy_every!r}")
    if not isinstance(self.num_critics, int) or self.num_critics < 1:
      raise ValueError(f"num_critics must be an integer >= 1, got {self.num_critics!r}")


class State(NamedTuple):
  """A learner's state: online and target networks, their optimizers' states, and settings."""
  policy: dict
  critic: dict
  target_policy: dict
  target_critic: dict
  policy_opt: optax.OptState
  critic_opt: optax.OptState
  steps: jax.Array  # () int32 updates done
  hparams: dict     # the config's dynamic settings (Config.DYNAMIC), as arrays


class Networks(NamedTuple):
  """What the functions below run: the policy, `num_critics` critics side by side, and
  `head(hparams)`, the critic's head (scalar or categorical) for a state's dynamic settings."""
  policy: networks.TanhPolicy
  critic: networks.Critic
  num_critics: int
  head: Callable[[dict], critics.Head]


def critic_outputs(nets: Networks, params, obs, action):
  """Every critic's outputs: (num_critics, ..., outputs), or (..., outputs) for one."""
  if nets.num_critics == 1:
    return nets.critic.apply(params, obs, action)
  return jax.vmap(lambda p: nets.critic.apply(p, obs, action))(params)


def lowest(nets: Networks, head: critics.Head, outputs):
  """(..., outputs) of the critic whose value is lowest, sample by sample."""
  if nets.num_critics == 1:
    return outputs
  index = jnp.argmin(head.value(outputs), axis=0)
  index = index.reshape((1,) + index.shape + (1,) * (outputs.ndim - 1 - index.ndim))
  return jnp.take_along_axis(outputs, index, axis=0)[0]


def lowest_value(nets: Networks, head: critics.Head, outputs):
  """(...,) the lowest of the critics' values, sample by sample."""
  values = head.value(outputs)
  return values.min(axis=0) if nets.num_critics > 1 else values


def init(nets: Networks, cfg: Config, obs_size: int, action_size: int, key, hparams=None):
  """A fresh State; `hparams` (default: the config's) are its dynamic settings."""
  hp = base.hparams(cfg) if hparams is None else hparams
  opt = optimizer(hp["learning_rate"], hp["max_grad_norm"])
  policy_key, critic_key = jax.random.split(key)
  obs, action = jnp.zeros((1, obs_size)), jnp.zeros((1, action_size))
  policy_params = nets.policy.init(policy_key, obs)
  if nets.num_critics > 1:
    critic = jax.vmap(lambda k: nets.critic.init(k, obs, action))(
        jax.random.split(critic_key, nets.num_critics))
  else:
    critic = nets.critic.init(critic_key, obs, action)
  return State(policy_params, critic, policy_params, critic, opt.init(policy_params),
               opt.init(critic), jnp.zeros((), jnp.int32), hp)


def policy(nets: Networks, state: State, obs):
  """The deterministic policy's actions (..., A)."""
  return nets.policy.apply(state.policy, obs)


def act(nets: Networks, cfg: Config, state: State, obs, key):
  """The policy's actions plus Gaussian noise of std sigma (mixed over envs with sigma_min),
  clipped to [-1, 1]."""
  action = policy(nets, state, obs)
  sigma = state.hparams["sigma"]
  if cfg.sigma_min is not None and action.ndim > 1:
    sigma = jnp.linspace(cfg.sigma_min, sigma, action.shape[0])[:, None]
  noise = sigma * jax.random.normal(key, action.shape)
  return jnp.clip(action + noise, -1.0, 1.0)


def critic_loss(critic_params, nets: Networks, head: critics.Head, state: State, batch):
  """The critics' mean TD loss against the target networks' n-step target, and their values
  (B,) (the lowest, with several critics)."""
  next_action = jnp.tanh(nets.policy.apply(state.target_policy, batch.next_obs, squash=False))
  next_out = lowest(nets, head, critic_outputs(nets, state.target_critic, batch.next_obs,
                                               next_action))
  target = jax.lax.stop_gradient(head.target(next_out[None], batch.reward, batch.discount))
  out = critic_outputs(nets, critic_params, batch.obs, batch.action)
  if nets.num_critics > 1:  # the critics' losses add up: each fits the same target
    return (jax.vmap(lambda o: head.loss(o, target).mean())(out).sum(),
            lowest_value(nets, head, out))
  return head.loss(out, target).mean(), head.value(out)


def policy_loss(policy_params, nets: Networks, head: critics.Head, state: State, batch):
  """Minus the (lowest) critic's mean value of the policy's actions, plus the action penalty;
  and the fraction of saturated actions."""
  # As acme's learners, the deterministic policy gradient is taken at the next observations.
  pre = nets.policy.apply(policy_params, batch.next_obs, squash=False)
  value = lowest_value(nets, head, critic_outputs(nets, state.critic, batch.next_obs,
                                                  jnp.tanh(pre)))
  loss = -value.mean() + state.hparams["action_penalty"] * jnp.mean(pre ** 2)
  return loss, jnp.mean(jnp.abs(pre) > _SATURATED)


POLICY_METRICS = ("policy_loss", "policy_grad_norm", "policy_saturated")


def policy_step(nets: Networks, cfg: Config, head: critics.Head, opt, state: State, batch,
                axis_name):
  """(policy params, optimizer state, metrics) after one gradient step of `policy_loss`; the
  metrics are scaled by `policy_every` (see Config)."""
  (p_loss, saturated), p_grads = jax.value_and_grad(policy_loss, has_aux=True)(
      state.policy, nets, head, state, batch)
  p_grads = pmean(p_grads, axis_name)
  p_updates, policy_opt = opt.update(p_grads, state.policy_opt)
  metrics = dict(zip(POLICY_METRICS, (p_loss, optax.tree.norm(p_grads), saturated)))
  return (optax.apply_updates(state.policy, p_updates), policy_opt,
          jax.tree.map(lambda m: m * cfg.policy_every, metrics))


def update(nets: Networks, cfg: Config, state: State, batch, key, axis_name=None):
  """One learner step: the critics', the policy's (at one update in `policy_every`), then the
  target networks'. Returns the new state and the step's metrics."""
  del key  # the update is deterministic given the batch
  hp = state.hparams
  head = nets.head(hp)
  opt = optimizer(hp["learning_rate"], hp["max_grad_norm"])
  (c_loss, q), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(state.critic, nets,
                                                                      head, state, batch)
  c_grads = pmean(c_grads, axis_name)
  c_updates, critic_opt = opt.update(c_grads, state.critic_opt)
  critic = optax.apply_updates(state.critic, c_updates)
  learn = functools.partial(policy_step, nets, cfg, head, opt, state, batch, axis_name)
  if cfg.policy_every == 1:
    policy_params, policy_opt, p_metrics = learn()
  else:
    keep = lambda: (state.policy, state.policy_opt,
                    dict.fromkeys(POLICY_METRICS, jnp.zeros((), jnp.float32)))
    policy_params, policy_opt, p_metrics = jax.lax.cond(
        state.steps % cfg.policy_every == 0, learn, keep)
  steps = state.steps + 1
  target_policy, target_critic = update_targets(
      steps, hp["target_update_period"], (policy_params, critic),
      (state.target_policy, state.target_critic))
  new = State(policy_params, critic, target_policy, target_critic, policy_opt, critic_opt,
              steps, hp)
  metrics = {"critic_loss": c_loss, "q_mean": q.mean(), "q_min": q.min(), "q_max": q.max(),
             "critic_grad_norm": optax.tree.norm(c_grads), **p_metrics}
  return new, pmean(metrics, axis_name)


def exported_policy(params: dict, cfg: Config) -> tuple[list, str]:
  """The deterministic policy as `export` writes it: TanhPolicy's LayerNormMLP, then tanh."""
  return networks.exported_mlp(params["params"]["LayerNormMLP_0"], len(cfg.policy_layers) + 1,
                               False, cfg.compute_dtype), "tanh"


def make(obs_size: int, action_size: int, cfg: Config,
         head: Callable[[dict], critics.Head]) -> Agent:
  """The agent: the functions above on these networks. `head(hparams)` is the critic's head
  for a state's dynamic settings."""
  dtype = COMPUTE_DTYPES[cfg.compute_dtype]
  hp = base.hparams(cfg)
  nets = Networks(networks.TanhPolicy(cfg.policy_layers, action_size, dtype),
                  networks.Critic(cfg.critic_layers, head(hp).num_outputs, dtype,
                                  norm_every=cfg.critic_norm),
                  cfg.num_critics, head)
  return Agent(init=functools.partial(init, nets, cfg, obs_size, action_size),
               act=functools.partial(act, nets, cfg), policy=functools.partial(policy, nets),
               update=functools.partial(update, nets, cfg), n_step=cfg.n_step, hparams=hp)
