"""D4PG: a deterministic policy with a categorical critic, after acme's JAX learner.

    agent = d4pg.make(obs_size, action_size, d4pg.Config())     # or d4pg.DEFAULTS["cpu"]
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from mjx_hopper.agents import distributional
from mjx_hopper.agents import base, critics, dpg
from mjx_hopper.agents.base import Agent


@dataclasses.dataclass(frozen=True)
class Config(dpg.Config):
  """Defaults are the NMA notebook's networks and acme's D4PG hyperparameters."""

  DYNAMIC: ClassVar[tuple[str, ...]] = dpg.Config.DYNAMIC + ("vmin", "vmax")
  vmin: float = -150.0
  vmax: float = 150.0
  num_atoms: int = 51

  def __post_init__(self):
    super().__post_init__()
    distributional.check_support(self.vmin, self.vmax, self.num_atoms)


# "acme": the NMA notebook's acme settings. "gpu" and "cpu" (base.named_defaults) also widen the
# critic's support, since a hopping Hopper earns ~2.5 per step, a discounted value of ~250 (above
# acme's vmax of 150).
DEFAULTS = base.named_defaults(Config, tuned={"vmax": 450.0})

State = dpg.State


def make(obs_size: int, action_size: int, cfg: Config = Config()) -> Agent:
  """D4PG: dpg's functions with a categorical critic over the state's [vmin, vmax]."""
  return dpg.make(obs_size, action_size, cfg,
                  lambda hp: critics.categorical(hp["vmin"], hp["vmax"], cfg.num_atoms))


# The learner figures on the terminal line (log.csv has all of them): a bounded critic loss, and a
# mean Q that follows the returns' scale rather than running away.
LEARNER_FIELDS = (("critic_loss", "critic loss {}"), ("q_mean", "Q {}"))
TINY = {"policy_layers": (16,), "critic_layers": (16,), "n_step": 3, "num_atoms": 11}
