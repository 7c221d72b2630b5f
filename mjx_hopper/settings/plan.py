"""A run's settings resolved once, at its start (`resolve`), into a frozen `Plan` that everything
after reads: its task, members, agent and trainer configs, saved config, and the keys that say
which configurations share programs. Nothing after the start computes them again."""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

from mjx_hopper import agents
from mjx_hopper.settings.config import RunConfig
from mjx_hopper.settings.training import TrainConfig

# A dynamic setting that also shapes the programs: the longest n-step window the replay reads.
SHAPING_DYNAMIC = ("n_step",)


class TrainerKey(NamedTuple):
  """Everything a trainer is made from, comparable and hashable (not out_dir, budgets or seeds):
  the task's class and its settings with the episode length, the agent and its config, the
  trainer's layout, the evaluation's episodes, the number of members, whether their update
  counts are dynamic, and the physics engine."""
  task: type
  task_settings: tuple
  agent: str
  agent_config: tuple
  train: TrainConfig
  eval_episodes: int
  members: int
  dynamic_updates: bool
  physics: str


@dataclasses.dataclass(frozen=True)
class Plan:
  """`cfg` resolved: its task's class and constructor settings (episode_steps included), each
  member's seed and swept values, the agent's config (a sweep's largest n-step window), the
  trainer's (a sweep's largest replay ratio), the saved config (a checkpoint's config item and
  config.json, its record added at each save) with the defaults it is checked with, and the
  trainer's keys (`key`, everything it is made from; `program_key`, what shapes its programs,
  not the dynamic settings, which they read from the state; `identity`, the text they are kept
  as traced under, None for code of one's own), and whether its evaluations run on the host's
  CPU beside training (`RunConfig.evaluates_on_host`; never over processes: one process's
  choice)."""
  cfg: RunConfig
  task: type
  task_settings: dict
  members: tuple
  agent_config: Any
  train: TrainConfig
  saved: dict
  saved_defaults: dict
  key: TrainerKey
  program_key: TrainerKey
  identity: str | None
  on_host: bool


def resolve(cfg: RunConfig, num_members: int | None = None, processes: int = 1,
            backend: str = "cpu") -> Plan:
  """`cfg`'s plan, for a trainer of its members (or of `num_members` of them: a process's share)
  over `processes` processes, on `backend` (as `jax.default_backend()` names it)."""
  task, settings, members = cfg.task(), cfg.task_settings(), tuple(cfg.member_settings())
  agent_config, train = cfg.agent_config(), cfg.train_config()
  saved = cfg.saved(list(range(len(members))), processes, settings, agent_config)
  saved_defaults = cfg.saved_defaults(agent_config)
  on_host = cfg.evaluates_on_host(backend, len(members)) and processes == 1
  key = TrainerKey(task, _frozen(settings), cfg.agent, _frozen(dataclasses.asdict(agent_config)),
                   train, cfg.eval_episodes, num_members or len(members),
                   "replay_ratio" in cfg.grid, cfg.physics)
  dynamic = set(type(agent_config).DYNAMIC) - set(SHAPING_DYNAMIC)
  program_key = key._replace(agent_config=tuple(
      kv for kv in key.agent_config if kv[0] not in dynamic))
  # Code of one's own may change without its name changing: it is traced afresh.
  own = all(x.__module__.startswith("mjx_hopper.") for x in (task, agents.spec(cfg.agent).make))
  return Plan(cfg, task, settings, members, agent_config, train, saved, saved_defaults, key,
              program_key, repr(program_key) if own else None, on_host)


def _frozen(x):
  """`x` with its dicts and lists made tuples, so that a config read back from JSON compares
  equal to the one it was written from."""
  if isinstance(x, dict):
    return tuple(sorted((k, _frozen(v)) for k, v in x.items()))
  if isinstance(x, (list, tuple)):
    return tuple(_frozen(v) for v in x)
  return x
