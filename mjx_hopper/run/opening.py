"""A run's opening, from its settings resolved once (`settings.plan`): its trainer and
checkpoints built, its newest readable checkpoint restored (or a fresh state made) while its
programs compile, and the `Parts` that own each step between chunks assembled around them,
complete."""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import time
from typing import Any, Callable, NamedTuple

import jax

from mjx_hopper import agents, store
from mjx_hopper.core import evaluator as evaluation, pbt, start, train
from mjx_hopper.core.evaluator import Evaluator
from mjx_hopper.core.members import Members
from mjx_hopper.process import distributed
from mjx_hopper.run import sweep, trainers
from mjx_hopper.run.logger import Logger
from mjx_hopper.settings.config import RunConfig
from mjx_hopper.settings.plan import Plan
from mjx_hopper.store.run_folder import RunFolder, check_processes

ProgressFn = Callable[[int, dict], Any]


@dataclasses.dataclass
class Parts:
  """One call of `run`: its config and the parts that own each step between chunks."""
  cfg: RunConfig
  folder: RunFolder
  trainer: train.Trainer
  members: Members
  evaluator: Evaluator
  started: start.Started | None  # the programs that train it (None: nothing left to train)
  pbt_step: Callable | None
  saver: store.Saver
  logger: Logger
  display: sweep.Report
  until: "Until"
  progress_fn: ProgressFn | None
  say: Callable[[str], None]


@dataclasses.dataclass(frozen=True)
class Built:
  """What a run's start builds from its `plan`: its folder, checkpoints' folder and their
  manager (None: a fresh folder) and trainer."""
  plan: Plan
  folder: RunFolder
  checkpoints: str
  mngr: Any
  trainer: train.Trainer

  def compile(self) -> start.Started:
    """The programs that train the run, compiling (`start.start`)."""
    return start.start(self.trainer, functools.partial(trainers.init, self.plan, self.trainer),
                       functools.partial(evaluation.lower, self.trainer, self.plan))


def open_run(plan: Plan, folder: RunFolder, checkpoint_dir: str | None, say, progress_fn
             ) -> tuple[Parts, Restored]:
  """The parts of a run, and what it trains from (a fresh state, or the newest readable
  checkpoint's), with the training chunk compiling meanwhile, then the evaluation."""
  t_start = time.perf_counter()
  built = build(plan, folder, checkpoint_dir)
  restored = restore(built, say)
  return assemble(built, restored, say, progress_fn, t_start), restored


def build(plan: Plan, folder: RunFolder, checkpoint_dir: str | None) -> Built:
  """What the run's start builds; a checkpoint of another run is refused before anything is
  built."""
  os.makedirs(folder.path, exist_ok=True)
  checkpoint_dir = checkpoint_dir or folder.checkpoints
  mngr = checked_manager(plan, checkpoint_dir)
  trainer = trainers.build(plan)
  return Built(plan, folder, checkpoint_dir, mngr, trainer)


class Restored(NamedTuple):
  """What a run trains from: the newest readable checkpoint's contents or a fresh state's
  (`store.read_latest`), its env steps, the programs that train on from it (None where nothing
  is left to train) and the run's Saver."""
  resumed: Any
  env_steps: int
  started: start.Started | None
  saver: store.Saver


def restore(built: Built, say) -> Restored:
  """What the run trains from. A fresh run compiles while the checkpoints open; a resumed one
  that trains on, while its checkpoint is read."""
  plan, cfg, per_iteration = built.plan, built.plan.cfg, built.trainer.config.steps_per_iteration
  started = None if built.mngr is not None else built.compile()
  saver = store.Saver(built.mngr or store.manager(built.checkpoints, cfg.keep_checkpoints),
                      plan.saved, cfg.checkpoint_minutes, per_iteration, say)
  if started is None and (saver.mngr.latest_step() or 0) * per_iteration < cfg.total_env_steps:
    started = built.compile()
  resumed = store.read_latest(saver.mngr, started.state.result() if started
                              else trainers.init(plan, built.trainer),
                              plan.saved, say, plan.saved_defaults)
  if distributed.primary():
    built.folder.write_config(plan.saved)  # once resuming is agreed
  env_steps = built.trainer.env_steps(resumed.state)
  if env_steps >= cfg.total_env_steps:
    started = None  # nothing left to train
  elif started is None:  # an older step than the newest was read
    started = built.compile()
  return Restored(resumed, env_steps, started, saver)


def assemble(built: Built, restored: Restored, say, progress_fn, t_start: float) -> Parts:
  """The parts that own each step between chunks, complete."""
  cfg, mine, trainer = built.plan.cfg, built.plan.members, built.trainer
  resumed, started = restored.resumed, restored.started
  primary = distributed.primary()
  say(header(cfg, trainer, len(mine)))
  if warning := gpu_sizes_warning(cfg.agent_defaults, jax.devices()[0].platform):
    say(warning)
  until = Until(cfg, t_start)
  members = Members(list(mine), list(range(len(mine))), single=len(mine) == 1,
                    pbt=cfg.pbt is not None, target=cfg.stop_at_return, say=say)
  members.load_record(resumed.record)
  evaluator = Evaluator(trainer, built.plan, started and started.evaluation, resumed.best)
  display = sweep.Report(cfg.grid, members, say)
  logger = Logger(built.folder.log if primary else None, cfg.log_every, display.logger_print,
                  agents.learner_fields(cfg.agent), cfg.tensorboard_dir if primary else None,
                  start_step=restored.env_steps,
                  id_fields=display.id_fields, wandb_project=cfg.wandb if primary else None,
                  wandb_config=built.plan.saved)
  pbt_step = cfg.pbt and pbt.make_step(cfg.pbt, cfg.grid, trainer, cfg.seed, say)
  return Parts(cfg, built.folder, trainer, members, evaluator,
               started, pbt_step, restored.saver, logger, display,
               until, progress_fn, say)


def checked_manager(plan: Plan, checkpoint_dir: str):
  """The checkpoint manager of a folder that holds checkpoints, once they are of this run (its
  config and number of processes), before anything is built or compiled for it; None for a
  fresh folder. A checkpoint of another run is a ConfigMismatch."""
  if not (os.path.isdir(checkpoint_dir) and os.listdir(checkpoint_dir)):
    return None
  mngr = store.manager(checkpoint_dir, plan.cfg.keep_checkpoints)
  check_processes(mngr, distributed.count())
  store.check_config(mngr, plan.saved, plan.saved_defaults)
  return mngr


class Until:
  """When the run ends: at its env steps, or at the first chunk's end past its deadline (so a
  run trains at least one chunk, however long its programs take to compile)."""

  def __init__(self, cfg: RunConfig, t_start: float):
    self.t_start, self.total = t_start, cfg.total_env_steps
    self.deadline = t_start + 60 * cfg.max_minutes if cfg.max_minutes else math.inf

  def elapsed(self) -> float:
    """Seconds since the run began."""
    return time.perf_counter() - self.t_start

  def total_reached(self, env_steps: int) -> bool:
    """Whether `env_steps` is the run's total: it trains no further chunk."""
    return env_steps >= self.total

  def reached(self, env_steps: int) -> bool:
    """Whether the run ends after a chunk that ends at `env_steps`: its total reached, or its
    deadline passed."""
    return self.total_reached(env_steps) or time.perf_counter() >= self.deadline


def gpu_sizes_warning(agent_defaults: str, platform: str) -> str | None:
  """A line for a run of the gpu settings (the gpu preset's, or the agent's gpu defaults) where
  JAX has no GPU (a CPU install, as on Colab's CPU runtime): its sizes would train slowly."""
  if agent_defaults == "gpu" and platform == "cpu":
    return ("the gpu settings' sizes are a GPU's, and JAX runs on the CPU here: install JAX's GPU "
            "build (bash scripts/setup.sh cuda), or train the cpu preset (--preset cpu, and "
            "--agent-defaults cpu where it is given)")
  return None


def header(cfg: RunConfig, trainer: train.Trainer, count: int) -> str:
  """The run's first line: its task, agent, members, envs, physics (where not MJX), devices and
  chunk."""
  single = count == 1
  config, each = trainer.config, "" if single else " each"
  return (f"{cfg.task_id} with {cfg.agent} ({cfg.agent_defaults}): "
          f"{'' if single else f'{count} members, '}{config.num_envs} envs{each}"
          f"{' in MuJoCo C' if cfg.physics == 'c' else ''} on "
          f"{len(jax.devices())} {jax.devices()[0].platform} device(s)"
          f"{f' of {distributed.count()} processes' if distributed.count() > 1 else ''}, "
          f"{config.steps_per_chunk:,} env steps and "
          f"{config.updates_per_iteration * config.iterations_per_chunk:,} updates per chunk"
          f"{'' if single else ' per member'}")

