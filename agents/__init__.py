"""Functional RL agents in JAX: D4PG, DDPG, MPO and DMPO (MPO with a categorical critic).

    from mjx_hopper import agents
    cfg = agents.config("d4pg", preset="cpu", sigma=0.2)
    agent = agents.make("d4pg", obs_size, action_size, cfg)
"""

from __future__ import annotations

import dataclasses

from mjx_hopper.agents import d4pg, ddpg, mpo
from mjx_hopper.agents.base import Agent

# name -> (make, presets)
_AGENTS = {
    "d4pg": (d4pg.make, d4pg.PRESETS),
    "ddpg": (ddpg.make, ddpg.PRESETS),
    "mpo": (mpo.make, mpo.PRESETS),
    "dmpo": (mpo.make, mpo.DMPO_PRESETS),
}


def list_agents() -> list[str]:
  """The names `config` and `make` accept."""
  return sorted(_AGENTS)


def _lookup(name: str):
  if name not in _AGENTS:
    raise ValueError(f"unknown agent {name!r}; valid agents are {list_agents()}")
  return _AGENTS[name]


def config(name: str, preset: str = "seed", **overrides):
  """The named preset's config for agent `name`, with fields replaced by `overrides`."""
  presets = _lookup(name)[1]
  if preset not in presets:
    raise ValueError(f"unknown preset {preset!r} for {name}; valid presets are "
                     f"{sorted(presets)}")
  cfg = presets[preset]
  fields = {f.name for f in dataclasses.fields(cfg)}
  unknown = sorted(set(overrides) - fields)
  if unknown:
    raise ValueError(f"unknown {name} settings {unknown}; valid settings are {sorted(fields)}")
  return dataclasses.replace(cfg, **overrides)


def make(name: str, obs_size: int, action_size: int, cfg=None) -> Agent:
  """Builds agent `name` for these sizes, with `cfg` (default: its "seed" preset)."""
  make_fn, presets = _lookup(name)
  return make_fn(obs_size, action_size, presets["seed"] if cfg is None else cfg)


__all__ = ["Agent", "config", "d4pg", "ddpg", "list_agents", "make", "mpo"]
