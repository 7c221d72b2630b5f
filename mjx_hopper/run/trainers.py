"""A run's trainer and its fresh state, from its plan (`settings.plan`): `build` (kept while the
programs are the same) and `init`."""

from __future__ import annotations

import hashlib

import jax

from mjx_hopper import agents, envs
from mjx_hopper.core import train
from mjx_hopper.process import ledger
from mjx_hopper.settings.plan import Plan


_last_built: list = [None]  # the program_key of the trainer this process built last


def build(plan: Plan) -> train.Trainer:
  """The compiled trainer of `plan` (`settings.plan.resolve`), after checking its task's reward.
  Where the trainer built last in this process had other programs, JAX's in-memory caches are
  emptied first: once full, they change how the next programs are traced, and so their keys in
  the compile cache, and a run after other work in the same process (a notebook's earlier
  cells) would compile what the cache holds. The same programs again (a resume, another seed or
  learning rate: `plan.program_key`) keep them, so a second run of them neither traces nor
  compiles."""
  if plan.program_key != _last_built[0]:
    jax.clear_caches()
  _last_built[0] = plan.program_key
  return assemble(plan)


def assemble(plan: Plan) -> train.Trainer:
  """`build`'s trainer, JAX's in-memory caches as they are. Where a compile ledger is kept, it
  notes the trainer's configuration (`process.ledger`)."""
  key = plan.key
  env = plan.cfg.make_env(plan.task_settings)
  envs.check_task(env)
  agent = agents.make(key.agent, env.observation_size, env.action_size, plan.agent_config)
  ledger.note("trainer", f"{key.task.__name__} {key.agent} x{key.members} "
              + hashlib.sha256(repr(plan.program_key).encode()).hexdigest()[:12])
  return train.make_trainer(env, agent, key.train, eval_episodes=key.eval_episodes,
                            num_members=key.members, dynamic_updates=key.dynamic_updates,
                            identity=plan.identity)


def init(plan: Plan, trainer: train.Trainer, members: list[dict] | None = None,
         begin: bool = True) -> train.TrainState:
  """The fresh TrainState of `members` (of `plan.members`; default all), each from its own
  seed's key and with its own swept values: a member starts as the single run of its settings.
  begin=False: its envs blank (Trainer.init)."""
  members = plan.members if members is None else members
  return trainer.init([m["seed"] for m in members],
                      {name: [m[name] for m in members] for name in plan.cfg.grid}, begin)
