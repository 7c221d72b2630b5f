"""Functional RL agents (JAX, flax, optax): D4PG, DDPG, MPO and DMPO (MPO with D4PG's
categorical critic), and `register` for an agent of your own.

    from mjx_hopper import agents
    cfg = agents.config("d4pg", "cpu", sigma=0.2)
    agent = agents.make("d4pg", obs_size, action_size, cfg)
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any, Callable, NamedTuple

from mjx_hopper.agents import d4pg, ddpg, dpg, mpo
from mjx_hopper.agents.base import Agent

REQUIRED_DEFAULTS = ("cpu", "gpu")  # the named defaults every agent declares


class Spec(NamedTuple):
  """What an agent declares: how to build it, its named defaults (configs), the learner metrics its
  terminal line shows ((metric, "text {}") pairs), settings small enough for tests, and its
  exported policy (see `register`)."""
  make: Callable[[int, int, Any], Agent]
  defaults: dict[str, Any]
  learner_fields: tuple[tuple[str, str], ...]
  tiny: dict
  exported_policy: Callable[[Any, Any], tuple[list, str]] | None


_AGENTS: dict[str, Spec] = {}


def register(name: str, make: Callable[[int, int, Any], Agent], defaults: dict[str, Any],
             learner_fields: tuple[tuple[str, str], ...] = (), tiny: dict | None = None,
             exported_policy: Callable[[Any, Any], tuple[list, str]] | None = None) -> None:
  """Makes agent `name` trainable everywhere an agent's name is taken. `make(obs_size,
  action_size, config)` builds it; `defaults` ({name: config dataclass}) must hold "cpu" and
  "gpu"; `learner_fields` name the metrics of its `update` shown on the terminal; `tiny`
  overrides the config for the short runs of tests and the notebook's quick mode.

  `exported_policy(policy_params, config) -> (layers, output)` lets `mjx_hopper.faces.export` write
  its deterministic policy, from its state's `policy`, as NumPy layers: each an (arrays,
  structure) pair of `networks.exported_dense`, and the output "tanh" or "clip". Without it,
  the agent trains but cannot be exported."""
  missing = [d for d in REQUIRED_DEFAULTS if d not in defaults]
  if missing:
    raise ValueError(f"agent {name!r} must declare the defaults {list(REQUIRED_DEFAULTS)}; it "
                     f"lacks {missing}")
  if not all(dataclasses.is_dataclass(c) for c in defaults.values()):
    raise ValueError(f"agent {name!r}'s defaults must be config dataclasses, got {defaults!r}")
  _AGENTS[name] = Spec(make, dict(defaults), tuple(learner_fields), dict(tiny or {}),
                       exported_policy)


register("d4pg", d4pg.make, d4pg.DEFAULTS, d4pg.LEARNER_FIELDS, d4pg.TINY, dpg.exported_policy)
register("ddpg", ddpg.make, ddpg.DEFAULTS, ddpg.LEARNER_FIELDS, ddpg.TINY, dpg.exported_policy)
register("mpo", mpo.make, mpo.DEFAULTS, mpo.LEARNER_FIELDS, mpo.TINY, mpo.exported_policy)
register("dmpo", mpo.make, mpo.DMPO_DEFAULTS, mpo.LEARNER_FIELDS, mpo.DMPO_TINY,
         mpo.exported_policy)


def list_agents() -> list[str]:
  """The names `config` and `make` accept."""
  return sorted(_AGENTS)


def spec(name: str) -> Spec:
  """What agent `name` declared: a registered name, or `module:name`, whose module's import
  registers it (`register`), as the CLI's `--agent my_agents:linear`; an unknown name is a
  ValueError listing the known ones."""
  if name not in _AGENTS and ":" in name:
    module, _, registered = name.partition(":")
    try:
      importlib.import_module(module)
    except ImportError as error:
      raise ValueError(f"cannot import the agent {name!r}: {error} (the module must be "
                       "importable from the current directory or sys.path)") from None
    if registered not in _AGENTS:
      raise ValueError(f"module {module!r} registers no agent {registered!r} "
                       f"(agents.register); registered agents are {list_agents()}")
    return _AGENTS[registered]
  if name not in _AGENTS:
    raise ValueError(f"unknown agent {name!r}; valid agents are {list_agents()}, or an agent of "
                     "your own as 'module:name'")
  return _AGENTS[name]


def learner_fields(name: str) -> tuple[tuple[str, str], ...]:
  """The (metric, "text {}") pairs agent `name`'s terminal line shows."""
  return spec(name).learner_fields


def config(name: str, defaults: str | None = None, **overrides):
  """Agent `name`'s config: its named defaults `defaults` (None: "acme", the seed's settings,
  where the agent declares them, else "cpu") with fields replaced by `overrides`."""
  named = spec(name).defaults
  if defaults is None:
    defaults = "acme" if "acme" in named else "cpu"
  if defaults not in named:
    raise ValueError(f"unknown defaults {defaults!r} for {name}; valid defaults are "
                     f"{sorted(named)}")
  cfg = named[defaults]
  fields = {f.name for f in dataclasses.fields(cfg)}
  unknown = sorted(set(overrides) - fields)
  if unknown:
    raise ValueError(f"unknown {name} settings {unknown}; valid settings are {sorted(fields)}")
  return dataclasses.replace(cfg, **overrides)


def make(name: str, obs_size: int, action_size: int, cfg=None) -> Agent:
  """Builds agent `name` for these sizes, with `cfg` (default: `config(name)`)."""
  return spec(name).make(obs_size, action_size, config(name) if cfg is None else cfg)


__all__ = ["Agent", "Spec", "config", "d4pg", "ddpg", "dpg", "learner_fields", "list_agents",
           "make", "mpo", "register", "spec"]
