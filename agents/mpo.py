"""MPO, and with `distributional=True` DMPO (a categorical critic), after acme's learner.

The E-step weights sampled actions by softmax(Q / temperature), a dual keeping their KL from
uniform near `epsilon`; the M-step fits the Gaussian policy to them under decoupled KL bounds on
its mean and std.

    agent = mpo.make(obs_size, action_size, mpo.Config(distributional=True))
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import optax

from mjx_hopper.agents import base, critics, distributional, networks
from mjx_hopper.agents.base import (COMPUTE_DTYPES, Agent, CommonConfig, optimizer, pmean,
                                    update_targets)

MIN_LOG_DUAL = -18.0   # raw dual values are clipped from below at this (as acme)
DUAL_FLOOR = 1e-8      # added after softplus, so that every dual is > 0
# "penalize" (acme's) clips the Gaussian's samples to [-1, 1] and adds an E-step that weights
# them by how little they leave the bounds (MO-MPO's action penalty); "squash" applies tanh.
ACTION_BOUNDS = ("penalize", "squash")


@dataclasses.dataclass(frozen=True)
class Config(CommonConfig):
  """Defaults are the NMA notebook's DMPO networks and acme's values; `distributional=True` is
  DMPO."""

  DYNAMIC: ClassVar[tuple[str, ...]] = CommonConfig.DYNAMIC + (
      "epsilon", "epsilon_mean", "epsilon_stddev", "epsilon_penalty", "init_log_temperature",
      "init_log_alpha_mean", "init_log_alpha_stddev", "dual_learning_rate", "vmin", "vmax")
  num_samples: int = 20              # actions sampled per state in the E-step
  epsilon: float = 0.1               # KL bound of the E-step's weights
  epsilon_mean: float = 2.5e-3       # per-dimension KL bound on the mean
  epsilon_stddev: float = 1e-6       # per-dimension KL bound on the std
  epsilon_penalty: float = 1e-3      # KL bound of the action-penalty E-step ("penalize")
  init_log_temperature: float = 10.0
  init_log_alpha_mean: float = 10.0
  init_log_alpha_stddev: float = 1000.0
  dual_learning_rate: float = 1e-2
  init_scale: float = 0.7            # the policy's initial std
  min_scale: float = 1e-6            # the policy's smallest std
  action_bounds: str = "penalize"    # or "squash"; see ACTION_BOUNDS
  distributional: bool = False       # DMPO: a categorical critic over these atoms
  vmin: float = -150.0
  vmax: float = 150.0
  num_atoms: int = 51

  def __post_init__(self):
    super().__post_init__()
    if not isinstance(self.num_samples, int) or self.num_samples < 1:
      raise ValueError(f"num_samples must be an integer >= 1, got {self.num_samples!r}")
    for name in ("epsilon", "epsilon_mean", "epsilon_stddev", "epsilon_penalty",
                 "dual_learning_rate", "init_scale"):
      if not getattr(self, name) > 0:
        raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
    if not self.min_scale >= 0:
      raise ValueError(f"min_scale must be >= 0, got {self.min_scale}")
    if self.action_bounds not in ACTION_BOUNDS:
      raise ValueError(f"action_bounds must be one of {list(ACTION_BOUNDS)}, got "
                       f"{self.action_bounds!r}")
    if self.distributional:
      distributional.check_support(self.vmin, self.vmax, self.num_atoms)


# "gpu" and "cpu" as every agent's (base.named_defaults), and as D4PG's the critic's support
# widened to [-150, 450] (DMPO). Both also loosen acme's std constraint, which keeps the std near
# its start for too long on the Hopper; a much looser one lets it collapse.
LOOSER_STD = dict(epsilon_stddev=1e-5, init_log_alpha_stddev=10.0)
DEFAULTS = base.named_defaults(Config, tuned=LOOSER_STD)
DMPO_DEFAULTS = base.named_defaults(Config, every={"distributional": True},
                                    tuned={"vmax": 450.0, **LOOSER_STD})


class Duals(NamedTuple):
  """Raw dual variables; the duals themselves are softplus(raw) + DUAL_FLOOR."""

  log_temperature: jax.Array          # ()
  log_alpha_mean: jax.Array           # (A,)
  log_alpha_stddev: jax.Array         # (A,)
  log_penalty_temperature: jax.Array  # ()


class State(NamedTuple):
  """A learner's state: online and target networks, the duals, their optimizers' states, and
  settings."""
  policy: dict
  critic: dict
  target_policy: dict
  target_critic: dict
  duals: Duals
  policy_opt: optax.OptState
  critic_opt: optax.OptState
  dual_opt: optax.OptState
  steps: jax.Array  # () int32 updates done
  hparams: dict     # the config's dynamic settings (Config.DYNAMIC), as arrays


def positive(raw: jax.Array) -> jax.Array:
  """A dual's value from its raw parameter: softplus, plus a floor."""
  return jax.nn.softplus(raw) + DUAL_FLOOR


def e_step(q: jax.Array, temperature: jax.Array, epsilon: float):
  """Weights softmax(q / temperature) over the N samples of q (N, B), without gradient, and
  the temperature's dual loss, which drives their KL from uniform towards `epsilon`."""
  tempered = jax.lax.stop_gradient(q) / temperature
  weights = jax.lax.stop_gradient(jax.nn.softmax(tempered, axis=0))
  log_mean_exp = jax.nn.logsumexp(tempered, axis=0) - math.log(q.shape[0])
  return weights, temperature * (epsilon + jnp.mean(log_mean_exp))


def decoupled_kl(target_mean, target_std, online_mean, online_std):
  """Per-dimension KLs (..., A) of the online mean and std, each with the other the target's."""
  kl_mean = 0.5 * jnp.square((online_mean - target_mean) / target_std)
  ratio = target_std / online_std
  kl_stddev = 0.5 * jnp.square(ratio) - jnp.log(ratio) - 0.5
  return kl_mean, kl_stddev


def kl_losses(kl: jax.Array, alpha: jax.Array, epsilon: float):
  """(policy penalty, alpha's dual loss, mean KL (A,)) for KLs (B, A) and duals alpha (A,)."""
  mean_kl = kl.mean(axis=0)
  penalty = jnp.sum(jax.lax.stop_gradient(alpha) * mean_kl)
  dual_loss = jnp.sum(alpha * (epsilon - jax.lax.stop_gradient(mean_kl)))
  return penalty, dual_loss, mean_kl


def gaussian_log_prob(x, mean, std):
  """(...,) log-density of x (..., A) under the diagonal Gaussian N(mean, std)."""
  z = (x - mean) / std
  return jnp.sum(-0.5 * jnp.square(z) - jnp.log(std) - 0.5 * math.log(2 * math.pi), axis=-1)


class Networks(NamedTuple):
  """What the functions below run: the Gaussian policy and the critic."""
  policy: networks.GaussianPolicy
  critic: networks.Critic


def critic_head(cfg: Config, hp: dict) -> critics.Head:
  """The critic's head for these dynamic settings: categorical (DMPO) or scalar (MPO)."""
  return (critics.categorical(hp["vmin"], hp["vmax"], cfg.num_atoms) if cfg.distributional
          else critics.scalar())


def optimizers(hp: dict):
  """(the networks' optimizer, the duals' optimizer) for these dynamic settings."""
  return (optimizer(hp["learning_rate"], hp["max_grad_norm"]),
          optax.adam(hp["dual_learning_rate"]))


def to_action(cfg: Config, u: jax.Array) -> jax.Array:
  """Env actions from Gaussian samples: tanh-squashed, or clipped to the bounds."""
  return jnp.tanh(u) if cfg.action_bounds == "squash" else jnp.clip(u, -1.0, 1.0)


def init(nets: Networks, cfg: Config, obs_size: int, action_size: int, key, hparams=None):
  """A fresh State; `hparams` (default: the config's) are its dynamic settings."""
  hp = base.hparams(cfg) if hparams is None else hparams
  opt, dual_opt = optimizers(hp)
  policy_key, critic_key = jax.random.split(key)
  obs, action = jnp.zeros((1, obs_size)), jnp.zeros((1, action_size))
  policy_params = nets.policy.init(policy_key, obs)
  critic = nets.critic.init(critic_key, obs, action)
  duals = Duals(jnp.asarray(hp["init_log_temperature"], jnp.float32),
                jnp.full(action_size, hp["init_log_alpha_mean"], jnp.float32),
                jnp.full(action_size, hp["init_log_alpha_stddev"], jnp.float32),
                jnp.asarray(hp["init_log_temperature"], jnp.float32))
  return State(policy_params, critic, policy_params, critic, duals, opt.init(policy_params),
               opt.init(critic), dual_opt.init(duals), jnp.zeros((), jnp.int32), hp)


def policy(nets: Networks, cfg: Config, state: State, obs):
  """The deterministic policy: the Gaussian's mean, as an env action."""
  return to_action(cfg, nets.policy.apply(state.policy, obs)[0])


def act(nets: Networks, cfg: Config, state: State, obs, key):
  """A sample of the Gaussian policy, as an env action."""
  mean, std = nets.policy.apply(state.policy, obs)
  return to_action(cfg, mean + std * jax.random.normal(key, mean.shape))


def critic_loss(critic_params, nets: Networks, head: critics.Head, batch, next_out):
  """The critic's mean TD loss against the target critic's outputs `next_out` (N, B, ...) at N
  sampled next actions, and its values (B,)."""
  target = head.target(next_out, batch.reward, batch.discount)
  out = nets.critic.apply(critic_params, batch.obs, batch.action)
  return head.loss(out, jax.lax.stop_gradient(target)).mean(), head.value(out)


def policy_loss(policy_params, duals: Duals, nets: Networks, cfg: Config, hp: dict, next_obs,
                target_mean, target_std, samples, q):
  """The E-step's weights of the target policy's `samples` (N, B, A) by their values `q`
  (N, B), the decoupled M-step's fit to them, the KL penalties and every dual's loss: (their
  sum, metrics)."""
  # As acme's learners, the policy is improved at the next observations.
  mean, std = nets.policy.apply(policy_params, next_obs)
  temperature = positive(duals.log_temperature)
  weights, loss_temperature = e_step(q, temperature, hp["epsilon"])
  kl_q = jnp.sum(weights * jnp.log(q.shape[0] * weights + 1e-30), axis=0).mean()
  stats = {"temperature": temperature, "kl_q_rel": kl_q / hp["epsilon"]}
  if cfg.action_bounds != "squash":
    penalty_temperature = positive(duals.log_penalty_temperature)
    cost = -jnp.linalg.norm(samples - jnp.clip(samples, -1.0, 1.0), axis=-1)
    penalty_weights, loss_penalty = e_step(cost, penalty_temperature, hp["epsilon_penalty"])
    weights = weights + penalty_weights
    loss_temperature = loss_temperature + loss_penalty
    stats["penalty_temperature"] = penalty_temperature
  # Decoupled M-step: the mean's fit with the target's std, and the std's with its mean.
  fit_mean = -jnp.sum(weights * gaussian_log_prob(samples, mean, target_std), axis=0).mean()
  fit_std = -jnp.sum(weights * gaussian_log_prob(samples, target_mean, std), axis=0).mean()
  kl_mean, kl_std = decoupled_kl(target_mean, target_std, mean, std)
  alpha_mean, alpha_std = positive(duals.log_alpha_mean), positive(duals.log_alpha_stddev)
  penalty_mean, dual_mean, mean_kl_mean = kl_losses(kl_mean, alpha_mean, hp["epsilon_mean"])
  penalty_std, dual_std, mean_kl_std = kl_losses(kl_std, alpha_std, hp["epsilon_stddev"])
  loss = (fit_mean + fit_std + penalty_mean + penalty_std + dual_mean + dual_std
          + loss_temperature)
  stats.update(policy_loss=fit_mean + fit_std, alpha_mean=alpha_mean.mean(),
               alpha_stddev=alpha_std.mean(),
               kl_mean_rel=mean_kl_mean.mean() / hp["epsilon_mean"],
               kl_stddev_rel=mean_kl_std.mean() / hp["epsilon_stddev"],
               policy_std=std.mean(), policy_std_min=std.min(), policy_std_max=std.max())
  return loss, stats


def update(nets: Networks, cfg: Config, state: State, batch, key, axis_name=None):
  """One learner step: N actions sampled from the target policy at each next observation, the
  critic's, the policy's and the duals' gradient steps, then the target networks'. Returns the
  new state and the step's metrics."""
  hp = state.hparams
  head = critic_head(cfg, hp)
  opt, dual_opt = optimizers(hp)
  target_mean, target_std = nets.policy.apply(state.target_policy, batch.next_obs)
  samples = target_mean + target_std * jax.random.normal(
      key, (cfg.num_samples,) + target_mean.shape)                         # (N, B, A)
  next_obs = jnp.broadcast_to(batch.next_obs, (cfg.num_samples,) + batch.next_obs.shape)
  next_out = nets.critic.apply(state.target_critic, next_obs, to_action(cfg, samples))
  (c_loss, q), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(
      state.critic, nets, head, batch, next_out)
  (_, stats), (p_grads, d_grads) = jax.value_and_grad(policy_loss, argnums=(0, 1),
                                                      has_aux=True)(
      state.policy, state.duals, nets, cfg, hp, batch.next_obs, target_mean, target_std,
      samples, head.value(next_out))
  c_grads, p_grads, d_grads = pmean((c_grads, p_grads, d_grads), axis_name)
  c_updates, critic_opt = opt.update(c_grads, state.critic_opt)
  p_updates, policy_opt = opt.update(p_grads, state.policy_opt)
  d_updates, dual_state = dual_opt.update(d_grads, state.dual_opt)
  critic = optax.apply_updates(state.critic, c_updates)
  policy_params = optax.apply_updates(state.policy, p_updates)
  duals = jax.tree.map(lambda d: jnp.maximum(d, MIN_LOG_DUAL),
                       optax.apply_updates(state.duals, d_updates))
  steps = state.steps + 1
  target_policy, target_critic = update_targets(
      steps, hp["target_update_period"], (policy_params, critic),
      (state.target_policy, state.target_critic))
  new = State(policy_params, critic, target_policy, target_critic, duals, policy_opt,
              critic_opt, dual_state, steps, hp)
  metrics = dict(stats, critic_loss=c_loss, q_mean=q.mean(), q_min=q.min(), q_max=q.max(),
                 critic_grad_norm=optax.tree.norm(c_grads),
                 policy_grad_norm=optax.tree.norm(p_grads))
  return new, pmean(metrics, axis_name)


def exported_policy(params: dict, cfg: Config) -> tuple[list, str]:
  """The deterministic policy (the Gaussian's mean) as `export` writes it: an activated
  LayerNormMLP, a float32 Dense, then tanh ("squash") or a clip to the bounds."""
  layers = networks.exported_mlp(params["params"]["LayerNormMLP_0"], len(cfg.policy_layers),
                                 True, cfg.compute_dtype)
  layers.append(networks.exported_dense(params["params"]["Dense_0"], "float32", False, "none"))
  return layers, "tanh" if cfg.action_bounds == "squash" else "clip"


def make(obs_size: int, action_size: int, cfg: Config = Config()) -> Agent:
  """MPO (DMPO with `cfg.distributional`): the functions above on these networks."""
  hp = base.hparams(cfg)
  nets = Networks(networks.GaussianPolicy(cfg.policy_layers, action_size, cfg.init_scale,
                                          cfg.min_scale, COMPUTE_DTYPES[cfg.compute_dtype]),
                  networks.Critic(cfg.critic_layers, critic_head(cfg, hp).num_outputs))
  return Agent(init=functools.partial(init, nets, cfg, obs_size, action_size),
               act=functools.partial(act, nets, cfg), policy=functools.partial(policy, nets, cfg),
               update=functools.partial(update, nets, cfg), n_step=cfg.n_step, hparams=hp)


# The terminal line's learner figures: the critic's loss, and the temperature, which should settle
# rather than collapse to its floor or keep growing.
LEARNER_FIELDS = (("critic_loss", "critic loss {}"), ("temperature", "temperature {}"))
TINY = {"policy_layers": (16,), "critic_layers": (16,), "n_step": 3, "num_samples": 4}
DMPO_TINY = {**TINY, "num_atoms": 11}
