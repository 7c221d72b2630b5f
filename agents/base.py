"""The agent interface, pure functions in optax's style, and what every agent shares: common
settings, the optimizer and target-network updates."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mjx_hopper.settings.fields import check_types

AgentState = Any


def n_step_transitions(hparams: dict) -> tuple:
  """The transitions that a state with these `hparams` learns from: (n_step, discount), its own
  settings of those names."""
  return hparams["n_step"], hparams["discount"]


class Agent(NamedTuple):
  """A learner as pure functions. Observations are (..., O), actions (..., A) in [-1, 1].

  init(key, hparams=None) -> state, which keeps `hparams` (default: the config's) as
    `state.hparams`
  act(state, obs, key) -> action, with exploration
  policy(state, obs) -> action, deterministic
  update(state, transitions, key, axis_name=None) -> (state, metrics); gradients are averaged
    over `axis_name` when given
  n_step: the longest n-step window `update` takes (the replay rows a sample reads)
  hparams: the config's dynamic settings as arrays
  transitions(hparams) -> (n_step, discount): the transitions that `update` takes, for a
    state's `hparams`, which the trainer samples (default: its n_step and discount settings)
  """

  init: Callable[[jax.Array], AgentState]
  act: Callable[[AgentState, jax.Array, jax.Array], jax.Array]
  policy: Callable[[AgentState, jax.Array], jax.Array]
  update: Callable[..., tuple[AgentState, dict[str, jax.Array]]]
  n_step: int
  hparams: dict
  transitions: Callable[[dict], tuple] = n_step_transitions


COMPUTE_DTYPES = {"float32": jnp.float32, "bfloat16": jnp.bfloat16}


@dataclasses.dataclass(frozen=True)
class CommonConfig:
  """Settings every agent has; defaults are the NMA notebook's networks and acme's values.

  DYNAMIC settings are read from the state's `hparams`, so one compiled program serves any of
  their values; the others shape the program.
  """

  DYNAMIC: ClassVar[tuple[str, ...]] = ("learning_rate", "discount", "n_step",
                                        "target_update_period", "max_grad_norm")

  policy_layers: tuple[int, ...] = (256, 256, 256)
  critic_layers: tuple[int, ...] = (512, 512, 256)
  learning_rate: float = 1e-4
  discount: float = 0.99
  n_step: int = 5
  target_update_period: int = 100    # updates between copies into the target networks
  max_grad_norm: float = 40.0        # acme's gradient clipping (by global norm)
  # The hidden layers' dtype; parameters, gradients, output layers and losses stay float32.
  compute_dtype: str = "float32"

  def __post_init__(self):
    check_types(self)
    if not isinstance(self.n_step, int) or self.n_step < 1:
      raise ValueError(f"n_step must be an integer >= 1, got {self.n_step!r}")
    if not 0.0 <= self.discount <= 1.0:
      raise ValueError(f"discount must be in [0, 1], got {self.discount}")
    if self.learning_rate <= 0:
      raise ValueError(f"learning_rate must be > 0, got {self.learning_rate}")
    if not isinstance(self.target_update_period, int) or self.target_update_period < 1:
      raise ValueError(f"target_update_period must be an integer >= 1, got "
                       f"{self.target_update_period!r}")
    if self.compute_dtype not in COMPUTE_DTYPES:
      raise ValueError(f"compute_dtype must be one of {list(COMPUTE_DTYPES)}, got "
                       f"{self.compute_dtype!r}")
    for name in ("policy_layers", "critic_layers"):
      layers = getattr(self, name)
      if not layers or any(not isinstance(n, int) or n < 1 for n in layers):
        raise ValueError(f"{name} must be a non-empty tuple of positive integers, got "
                         f"{layers!r}")


# What an agent's "gpu" and "cpu" defaults change in acme's values (its config class's own): they
# learn at 3e-4, and "cpu" has shallower networks, for a small CPU.
GPU_CHANGES = {"learning_rate": 3e-4}
CPU_CHANGES = {**GPU_CHANGES, "policy_layers": (256, 256), "critic_layers": (256, 256)}


def named_defaults(config: type[CommonConfig], every: dict | None = None,
                   tuned: dict | None = None) -> dict[str, CommonConfig]:
  """An agent's named defaults: "acme" (`config`'s own values), "gpu" and "cpu" (with
  GPU_CHANGES and CPU_CHANGES), each with `every` over it and the last two with `tuned`."""
  every, tuned = every or {}, tuned or {}
  return {"acme": config(**every), "gpu": config(**every, **GPU_CHANGES, **tuned),
          "cpu": config(**every, **CPU_CHANGES, **tuned)}


def hparams(cfg: CommonConfig) -> dict[str, np.ndarray]:
  """`cfg.DYNAMIC`'s settings as int32 or float32 arrays (NumPy's: made with JAX, each would be
  a program compiled at start)."""
  return {name: np.asarray(getattr(cfg, name),
                           np.int32 if isinstance(getattr(cfg, name), int) else np.float32)
          for name in cfg.DYNAMIC}


def optimizer(learning_rate, max_grad_norm) -> optax.GradientTransformation:
  """Adam after clipping the global gradient norm, as acme; either setting may be an array."""
  return optax.chain(optax.clip_by_global_norm(max_grad_norm), optax.adam(learning_rate))


def update_targets(steps: jax.Array, period: int, online, target):
  """acme's periodic hard update: `online` when `steps % period == 0`, else `target`."""
  copy = steps % period == 0
  return jax.tree.map(lambda o, t: jnp.where(copy, o, t), online, target)


def pmean(tree, axis_name: str | None):
  """`tree` averaged over the mapped axis `axis_name`, if any."""
  return tree if axis_name is None else jax.lax.pmean(tree, axis_name)
