"""DDPG: a deterministic policy with a scalar critic, after acme's learner.

    agent = ddpg.make(obs_size, action_size, ddpg.Config())
"""

from __future__ import annotations

from mjx_hopper.agents import base, critics, dpg
from mjx_hopper.agents.base import Agent


# The defaults are the NMA notebook's networks and acme's DDPG hyperparameters.
Config = dpg.Config

# "acme": the NMA notebook's acme settings; "gpu" and "cpu" as every agent's (base.named_defaults).
DEFAULTS = base.named_defaults(Config)

State = dpg.State


def make(obs_size: int, action_size: int, cfg: Config = Config()) -> Agent:
  """DDPG: dpg's functions with a scalar critic."""
  return dpg.make(obs_size, action_size, cfg, lambda hp: critics.scalar())


LEARNER_FIELDS = (("critic_loss", "critic loss {}"), ("q_mean", "Q {}"))
TINY = {"policy_layers": (16,), "critic_layers": (16,), "n_step": 3}
