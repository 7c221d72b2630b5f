"""A run's trainer and its fresh state, from its config: `build` (kept while the programs are
the same), `init`, and the keys that say which configurations share programs."""

from __future__ import annotations

import dataclasses
import hashlib
from typing import NamedTuple

import jax

from mjx_hopper import agents, envs
from mjx_hopper.core import train
from mjx_hopper.process import ledger
from mjx_hopper.settings.config import RunConfig
from mjx_hopper.settings.training import TrainConfig


_last_built: list = [None]  # the program_key of the trainer this process built last


class TrainerKey(NamedTuple):
  """Everything `build` makes a trainer from, comparable and hashable (not out_dir, budgets or
  seeds): the task's class (given as the class, an instance or a name) and its settings with the
  episode length, the agent and its config, the trainer's layout, the evaluation's episodes, the
  number of members, whether their update counts are dynamic, and the physics engine."""
  task: type
  task_settings: tuple
  agent: str
  agent_config: tuple
  train: TrainConfig
  eval_episodes: int
  members: int
  dynamic_updates: bool
  physics: str


def build(cfg: RunConfig, num_members: int | None = None) -> train.Trainer:
  """The compiled trainer of `cfg`'s members (or of `num_members` of them), after checking its
  task's reward. Where the trainer built last in this process had other programs, JAX's
  in-memory caches are emptied first: once full, they change how the next programs are traced,
  and so their keys in the compile cache, and a run after other work in the same process (a
  notebook's earlier cells) would compile what the cache holds. The same programs again (a
  resume, another seed or learning rate: `program_key`) keep them, so a second run of them
  neither traces nor compiles."""
  key = program_key(cfg, num_members)
  if key != _last_built[0]:
    jax.clear_caches()
  _last_built[0] = key
  return assemble(cfg, num_members, key)


def assemble(cfg: RunConfig, num_members: int | None = None,
             key: TrainerKey | None = None) -> train.Trainer:
  """`build`'s trainer, JAX's in-memory caches as they are (`key`: its `program_key`, where
  already known). Where a compile ledger is kept, it notes the trainer's configuration
  (`process.ledger`)."""
  key = key or program_key(cfg, num_members)
  env = cfg.make_env()
  envs.check_task(env)
  agent = agents.make(key.agent, env.observation_size, env.action_size, cfg.agent_config())
  ledger.note("trainer", f"{key.task.__name__} {key.agent} x{key.members} "
              + hashlib.sha256(repr(key).encode()).hexdigest()[:12])
  return train.make_trainer(env, agent, key.train, eval_episodes=key.eval_episodes,
                            num_members=key.members, dynamic_updates=key.dynamic_updates,
                            identity=identity(cfg, key))


def identity(cfg: RunConfig, key: TrainerKey | None = None) -> str | None:
  """The text under which the trainer's programs are kept as traced (`core.kept`): its
  `program_key` (`key`, where already known; a run of another learning rate reads the same
  programs), where its task's class and its agent's `make` are this package's own (code of
  one's own may change without its name changing, and is traced afresh)."""
  own = (envs.task_class(cfg.env), agents.spec(cfg.agent).make)
  if not all(x.__module__.startswith("mjx_hopper.") for x in own):
    return None
  return repr(key or program_key(cfg))


def trainer_key(cfg: RunConfig, num_members: int | None = None) -> TrainerKey:
  """The `TrainerKey` of `build(cfg, num_members)`."""
  return TrainerKey(envs.task_class(cfg.env), _frozen(cfg.task_settings()), cfg.agent,
                    _frozen(dataclasses.asdict(cfg.agent_config())), cfg.train_config(),
                    cfg.eval_episodes, num_members or len(cfg.member_settings()),
                    "replay_ratio" in cfg.grid, cfg.physics)


# A dynamic setting that also shapes the programs: the longest n-step window the replay reads.
SHAPING_DYNAMIC = ("n_step",)


def program_key(cfg: RunConfig, num_members: int | None = None) -> TrainerKey:
  """`trainer_key` without the agent's dynamic settings (but SHAPING_DYNAMIC): what shapes the
  trainer's programs, which read the dynamic settings from the state's `hparams` as data. Runs
  that differ only in those (another learning rate or noise) lower to the same programs."""
  key = trainer_key(cfg, num_members)
  dynamic = set(type(cfg.agent_config()).DYNAMIC) - set(SHAPING_DYNAMIC)
  return key._replace(agent_config=tuple(kv for kv in key.agent_config if kv[0] not in dynamic))


def _frozen(x):
  """`x` with its dicts and lists made tuples, so that a config read back from JSON compares
  equal to the one it was written from."""
  if isinstance(x, dict):
    return tuple(sorted((k, _frozen(v)) for k, v in x.items()))
  if isinstance(x, (list, tuple)):
    return tuple(_frozen(v) for v in x)
  return x


def init(cfg: RunConfig, trainer: train.Trainer, members: list[dict], begin: bool = True
         ) -> train.TrainState:
  """The fresh TrainState of `members` (from `cfg.member_settings()`), each from its own seed's
  key and with its own swept values: a member starts as the single run of its settings.
  begin=False: its envs blank (Trainer.init)."""
  return trainer.init([m["seed"] for m in members],
                      {name: [m[name] for m in members] for name in cfg.grid}, begin)
