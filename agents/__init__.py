"""Functional RL agents (JAX, flax, optax) for the MJX locomotion envs.

    from mjx_hopper import agents
    cfg = agents.config("d4pg", preset="cpu", sigma=0.2)
    agent = agents.make("d4pg", obs_size, action_size, cfg)
"""

from __future__ import annotations

import dataclasses

from mjx_hopper.agents import d4pg
from mjx_hopper.agents.base import Agent

_MODULES = {"d4pg": d4pg}


def list_agents() -> list[str]:
  """The names `config` and `make` accept."""
  return sorted(_MODULES)


def _module(name: str):
  if name not in _MODULES:
    raise ValueError(f"unknown agent {name!r}; valid agents are {list_agents()}")
  return _MODULES[name]


def config(name: str, preset: str = "seed", **overrides):
  """The named preset's config for agent `name`, with fields replaced by `overrides`."""
  module = _module(name)
  if preset not in module.PRESETS:
    raise ValueError(f"unknown preset {preset!r} for {name}; valid presets are "
                     f"{sorted(module.PRESETS)}")
  cfg = module.PRESETS[preset]
  fields = {f.name for f in dataclasses.fields(cfg)}
  unknown = sorted(set(overrides) - fields)
  if unknown:
    raise ValueError(f"unknown {name} settings {unknown}; valid settings are {sorted(fields)}")
  return dataclasses.replace(cfg, **overrides)


def make(name: str, obs_size: int, action_size: int, cfg=None) -> Agent:
  """Builds agent `name` for these sizes, with `cfg` (default: its "seed" preset)."""
  module = _module(name)
  return module.make(obs_size, action_size, module.PRESETS["seed"] if cfg is None else cfg)


__all__ = ["Agent", "config", "d4pg", "list_agents", "make"]
