"""The host loop: compiled training chunks, and between them the checks, logs, evaluations, PBT
steps, checkpoints and progress.

    from mjx_hopper import loop
    result = loop.run(loop.RunConfig(env="Hopper", agent="d4pg", total_env_steps=200_000))
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import sys
import time
from typing import Any, Callable

import jax
import numpy as np
from tqdm.auto import tqdm

from mjx_hopper import (agents, checkpoint, compat, parallel, pbt, runlock, runs, start, sweep,
                        train)
from mjx_hopper.config import RunConfig
from mjx_hopper.evaluator import Evaluator
from mjx_hopper.logger import Logger, check_services
from mjx_hopper.members import Members

ProgressFn = Callable[[int, dict], Any]


@dataclasses.dataclass
class Result:
  """What a run returns: its final state and trainer, its logged rows, its last evaluation, and
  each member's best agent and return."""

  state: train.TrainState
  trainer: train.Trainer
  history: list[dict]            # every logged row (train and eval)
  evaluation: dict[str, Any]     # the final evaluation's per-episode arrays
  best: Any = None               # the agent at each member's best evaluation (None before any)
  best_return: Any = None        # (members,) those evaluations' mean returns

  def policy(self, which: str = "best", member: int = 0):
    """Member `member`'s agent state without the member axis: at its best evaluation (before
    any, the latest), or with which="latest", the latest."""
    runs.check_which(which)
    agent = self.state.agent if which == "latest" or self.best is None else self.best
    return jax.tree.map(lambda x: x[member], agent)


def run(cfg: RunConfig, checkpoint_dir: str | None = None, progress: bool = True,
        print_fn=print, process: tuple[int, int] | None = None,
        progress_fn: ProgressFn | None = None) -> Result:
  """Trains until `total_env_steps`, evaluating every `eval_every` env steps and at the end.

  Writes `out_dir`/log.csv, config.json and checkpoints (to `checkpoint_dir`, default
  `out_dir`/checkpoints); a run whose checkpoint_dir holds one resumes from it. Ctrl-C or
  SIGTERM saves after the chunk in flight. `progress_fn(env_steps, metrics)` is called after
  every chunk and every evaluation with log.csv's fields (a sweep's: one value per member);
  returning False ends the run as `max_minutes` does, and an exception from it (or from a
  logger's sink) ends it as Ctrl-C does, then is raised. `process` = (index, count) trains this
  process's share of a sweep's members. The run holds `out_dir`'s lock (`runlock`) throughout.
  """
  check_services(cfg.wandb, cfg.tensorboard_dir)  # before a compile, which exit waits for
  say = _above_progress_bars(print_fn)
  with runlock.hold(_out_dir(cfg, process), say):
    parts, state = _open(cfg, checkpoint_dir, say, process, progress_fn)
    with checkpoint.StopRequest() as stop, parts.logger, _UserCode(parts, stop) as user:
      state = _train(parts, state, progress, stop)
    result = _finish(parts, state, stop)
  user.raise_error()
  return result


def resume(directory: str, progress: bool = True, print_fn=print, env: Any = None,
           progress_fn: ProgressFn | None = None, **changes) -> Result:
  """Continues the run checkpointed in `directory` with its saved config. `changes` replace
  fields that may change between a run and its resumption (total_env_steps, max_minutes, ...);
  one the saved state depends on is refused, naming it. `env` is the run's task, for one that
  cannot be imported (defined in a notebook)."""
  cfg = runs.saved_config(directory, print_fn, env)
  return run(dataclasses.replace(cfg, **changes), checkpoint_dir=directory, progress=progress,
             print_fn=print_fn, progress_fn=progress_fn)


@dataclasses.dataclass
class _Parts:
  """One call of `run`: its config and the parts that own each step between chunks."""
  cfg: RunConfig
  trainer: train.Trainer
  members: Members
  evaluator: Evaluator
  chunk: Callable
  pbt_step: Callable | None
  saver: checkpoint.Saver
  logger: Logger
  display: sweep.Report
  until: "_Until"
  progress_fn: ProgressFn | None
  say: Callable[[str], None]

  def env_steps(self, state) -> int:
    return train.iterations(state) * self.trainer.config.steps_per_iteration

  def pbt_due(self, before: int, env_steps: int) -> bool:
    """Whether PBT steps after the chunk from `before` to `env_steps`: at every `pbt.every`-th
    evaluation, but not at the run's end."""
    if self.cfg.pbt is None:
      return False
    period = self.cfg.eval_every * self.cfg.pbt.every
    return env_steps // period > before // period and env_steps < self.cfg.total_env_steps


def _train(p: _Parts, state: train.TrainState, progress: bool, stop) -> train.TrainState:
  """Chunks until the run's env steps or deadline, a stop (a signal, or progress_fn's False),
  its target, or every member diverged."""
  cfg, members, evaluator = p.cfg, p.members, p.evaluator
  env_steps = p.env_steps(state)
  bar = _progress_bar(cfg.total_env_steps, env_steps) if progress and not p.until.reached(
      env_steps) else None
  next_eval = (env_steps // cfg.eval_every + 1) * cfg.eval_every
  stopped = False  # by progress_fn
  while not (stopped or stop.requested or p.until.reached(env_steps) or members.done()):
    before, t0 = env_steps, time.perf_counter()
    state, metrics, agents_before = p.chunk(state)
    env_steps = p.env_steps(state)
    members.check(env_steps, metrics, p.chunk.finite(state.agent))
    state = p.chunk.freeze(state, agents_before, members.diverged)
    rate = (env_steps - before) * len(members) / (time.perf_counter() - t0)
    stopped = _log_train(p, state, env_steps, rate, metrics)
    if members.all_diverged():
      break  # this state is not evaluated, and never saved
    last = stopped or p.until.reached(env_steps)
    if env_steps >= next_eval or last:
      next_eval += cfg.eval_every
      evaluator.submit(env_steps, state.agent, members.diverged)
    pbt_now = p.pbt_due(before, env_steps)
    saving = p.saver.due()
    # The last evaluation, PBT's (which needs the returns) and a checkpoint's (which holds
    # them) wait; the others do not.
    for done in evaluator.collect(wait=last or pbt_now or saving):
      better = members.evaluated(done.env_steps, done.returns, done.diverged)
      evaluator.keep(done, better)
      stopped |= _log_evaluation(p, done)
    if pbt_now:
      state = p.pbt_step(state, evaluator.latest.returns, env_steps, members)
    if saving:
      p.saver.save(state, evaluator.best, members)
    _show(bar, p, env_steps, rate)
  _close(p, state, bar)
  return state


def _close(p: _Parts, state: train.TrainState, bar) -> None:
  """After the last chunk: the evaluations still running, the bar, the last checkpoint."""
  for done in p.evaluator.collect(wait=True):
    p.evaluator.keep(done, p.members.evaluated(done.env_steps, done.returns, done.diverged))
    _log_evaluation(p, done)
  if bar is not None:
    bar.close()
  if not p.members.all_diverged():
    p.saver.save(state, p.evaluator.best, p.members, last=True)
  p.saver.finish(state)


def _open(cfg: RunConfig, checkpoint_dir: str | None, say, process, progress_fn):
  """The parts of a run, and the state to train from (fresh, or the newest readable
  checkpoint's), with the training chunk compiling meanwhile, then the evaluation."""
  t_start = time.perf_counter()
  everyone = cfg.members()
  indices = parallel.process_share(len(everyone), process)
  mine = [everyone[i] for i in indices]
  if cfg.pbt is not None and len(mine) < 2:
    raise ValueError(f"PBT needs at least 2 members per process; this one has {len(mine)}")
  out_dir = _out_dir(cfg, process)
  os.makedirs(out_dir, exist_ok=True)
  checkpoint_dir = checkpoint_dir or os.path.join(out_dir, "checkpoints")
  trainer = runs.build(cfg, len(mine))
  members = Members(mine, indices, single=len(everyone) == 1, pbt=cfg.pbt is not None,
                    target=cfg.stop_at_return, say=say)
  evaluator = Evaluator(trainer, mine, cfg.eval_episodes, cfg.evaluates_on_host())
  fresh = functools.partial(runs.init, cfg, trainer, mine)
  started = functools.cache(lambda: start.start(trainer, fresh, evaluator))
  if not os.path.isdir(checkpoint_dir) or not os.listdir(checkpoint_dir):
    started()  # a fresh run: compiling from here, while the checkpoints and the log open
  saved_config = {**cfg.to_json(), "member_indices": indices}
  per_iteration = trainer.config.steps_per_iteration
  saver = checkpoint.Saver(checkpoint.manager(checkpoint_dir, cfg.keep_checkpoints),
                           saved_config, cfg.checkpoint_minutes, per_iteration, say)
  training = (saver.mngr.latest_step() or 0) * per_iteration < cfg.total_env_steps
  resumed = checkpoint.resume(
      saver.mngr, started().state.result() if training else fresh(), saved_config, say,
      defaults={"agent_config": _field_defaults(cfg.agent_config()), "env_settings": {}})
  members.restore(resumed.record)
  evaluator.best = resumed.best
  with open(os.path.join(out_dir, "config.json"), "w") as f:  # once resuming is agreed
    json.dump(saved_config, f, indent=1)
  env_steps = train.iterations(resumed.state) * per_iteration
  chunk = started() if env_steps < cfg.total_env_steps else None  # or an older step was read
  display = sweep.Report(cfg.grid, members, say)
  logger = Logger(os.path.join(out_dir, "log.csv"), cfg.log_every, display.logger_print,
                  agents.learner_fields(cfg.agent), cfg.tensorboard_dir, start_step=env_steps,
                  id_fields=display.id_fields, wandb_project=cfg.wandb,
                  wandb_config=saved_config)
  say(_header(cfg, trainer, len(mine), members.single))
  pbt_step = cfg.pbt and pbt.make_step(cfg.pbt, cfg.grid, trainer, cfg.seed, say)
  parts = _Parts(cfg, trainer, members, evaluator, _Chunk(chunk, evaluator, members), pbt_step,
                 saver, logger, display, _Until(cfg, t_start), progress_fn, say)
  return parts, resumed.state


def _out_dir(cfg: RunConfig, process) -> str:
  """The folder of this process's log, config and (by default) checkpoints."""
  return (os.path.join(cfg.out_dir, f"process{process[0]}") if process and process[1] > 1
          else cfg.out_dir)


class _Chunk:
  """Runs one compiled chunk, and freezes a sweep's members that diverged in it at their agents
  before it."""

  def __init__(self, started: start.Started | None, evaluator: Evaluator, members: Members):
    self.program, self._finite = (started.chunk, started.finite) if started else (None, None)
    self.single = members.single
    self._copy, self._select = evaluator.copy_agents, evaluator.select_agents

  def __call__(self, state: train.TrainState):
    """(state after the chunk, its metrics on the host, a sweep's agents before it (None for a
    single run, which stops when it diverges))."""
    before = None if self.single else self._copy(state.agent)
    state, metrics = self.program.result()(state)
    return state, jax.device_get(metrics), before

  def finite(self, agent) -> np.ndarray:
    """(members,): whether every float of each member's `agent` is finite."""
    return jax.device_get(self._finite.result()(agent))

  def freeze(self, state: train.TrainState, before, diverged: np.ndarray) -> train.TrainState:
    """`state` with the agents of the `diverged` members taken back to `before`."""
    if before is None or not diverged.any():
      return state
    return state._replace(agent=self._select(diverged, before, state.agent))


class _Until:
  """When the run ends: at its env steps or its deadline."""

  def __init__(self, cfg: RunConfig, t_start: float):
    self.t_start, self.total = t_start, cfg.total_env_steps
    self.deadline = t_start + 60 * cfg.max_minutes if cfg.max_minutes else math.inf

  def elapsed(self) -> float:
    return time.perf_counter() - self.t_start

  def reached(self, env_steps: int) -> bool:
    return env_steps >= self.total or time.perf_counter() >= self.deadline


class _UserCode:
  """Calls the user's code between chunks (progress_fn, the logger's sinks) so that its first
  exception ends the run as Ctrl-C does: the chunk is finished and saved (unless its state is
  no longer finite), then `raise_error` raises it. Any other error leaving the loop first waits
  for the save in flight and names the newest checkpoint."""

  def __init__(self, parts: _Parts, stop: checkpoint.StopRequest):
    self.parts, self.stop, self.error = parts, stop, None
    if parts.progress_fn is not None:
      parts.progress_fn = self._guard(parts.progress_fn, "progress_fn")
    parts.logger.write = self._guard(parts.logger.write, "the logger")

  def _guard(self, call: Callable, name: str) -> Callable:
    def guarded(*args, **kwargs):
      try:
        return call(*args, **kwargs)
      except Exception as error:  # noqa: BLE001 - raised once the state is saved
        if self.error is None:
          self.error = error
          self.stop.request(f"stopped by {name}'s {type(error).__name__}")
    return guarded

  def raise_error(self) -> None:
    if self.error is not None:
      raise self.error

  def __enter__(self) -> "_UserCode":
    return self

  def __exit__(self, kind, error, traceback) -> bool:
    if isinstance(error, (Exception, KeyboardInterrupt)) and not isinstance(
        error, checkpoint.SaveFailed):
      mngr = self.parts.saver.mngr
      try:
        checkpoint.finish(mngr)
        kept = mngr.latest_step()
        self.parts.say(f"the run stopped at an error: {mngr.directory} holds "
                       + (f"its checkpoint step {kept}, which resumes it" if kept is not None
                          else "no checkpoint of it"))
      except checkpoint.SaveFailed as failed:
        self.parts.say(f"the run stopped at an error; {failed}")
    return False


def _log_train(p: _Parts, state, env_steps: int, rate: float, metrics: dict) -> bool:
  """Logs a chunk: a row per member, and a sweep's terminal line. Returns whether progress_fn
  asked to stop."""
  updates = np.asarray(jax.device_get(state.updates))
  rows = [{"kind": "train", **p.members.tags(m), "env_steps": env_steps,
           "updates": int(updates[m]), "wall_s": p.until.elapsed(), "steps_per_s": rate,
           **{k: float(v[m]) for k, v in metrics.items()}} for m in range(len(p.members))]
  if not p.members.all_diverged():
    p.display.trained(env_steps, rate, metrics["episode_return"], p.cfg.log_every)
  return _log(p, env_steps, rows)


def _log_evaluation(p: _Parts, done) -> bool:
  """Logs a finished evaluation: a row per member, and a sweep's terminal line. Returns whether
  progress_fn asked to stop."""
  returns = done.result["return"]
  rows = [{"kind": "eval", **p.members.tags(m), "env_steps": done.env_steps,
           "wall_s": p.until.elapsed(), "eval_return": float(np.mean(returns[m])),
           "eval_return_std": float(np.std(returns[m])),
           "eval_length": float(np.mean(done.result["length"][m]))}
          for m in range(len(p.members))]
  p.display.evaluated(done.env_steps, done.returns)
  return _log(p, done.env_steps, rows)


def _log(p: _Parts, env_steps: int, rows: list[dict]) -> bool:
  """Writes `rows` to the logger, then hands them to progress_fn. Returns whether it returned
  False."""
  for row in rows:
    p.logger.write(row, force=row["kind"] == "eval")
  if p.progress_fn is None:
    return False
  metrics = dict(rows[0]) if p.members.single else {
      k: rows[0][k] if k == "kind" else np.array([row[k] for row in rows]) for k in rows[0]}
  return p.progress_fn(env_steps, metrics) is False


def _show(bar, p: _Parts, env_steps: int, rate: float) -> None:
  """Moves the progress bar (if any) to `env_steps`."""
  if bar is not None:
    bar.update(min(env_steps, p.cfg.total_env_steps) - bar.n)
    bar.set_postfix_str(p.display.status(rate, p.logger))


def _finish(p: _Parts, state: train.TrainState, stop) -> Result:
  """The run's last lines (a sweep's ranking and curves first) and its Result."""
  evaluation = None if p.evaluator.latest is None else p.evaluator.latest.result
  if p.members.single and evaluation is not None:
    evaluation = jax.tree.map(lambda x: x[0], evaluation)  # a single run is one member
  p.display.finish(p.logger.rows, os.path.dirname(p.logger.csv_path))
  directory = p.saver.mngr.directory
  if p.members.all_diverged():
    kept = p.saver.mngr.latest_step()
    p.say("training diverged; nothing was saved after it: "
          + (f"the last finite checkpoint is step {kept} in {directory}, which loop.resume "
             "continues (a lower learning rate may avoid it)" if kept is not None
             else "no checkpoint was saved before it"))
  why = stop.reason if stop.requested else p.members.outcome()
  parts = [f"{why}: {p.env_steps(state):,} env steps in {p.until.elapsed():.0f} s"]
  if p.members.single and evaluation is not None:
    parts.append(f"evaluation return {np.mean(evaluation['return']):.1f} over "
                 f"{len(evaluation['return'])} episodes")
  parts.append(f"log: {p.logger.csv_path}")
  if p.cfg.tensorboard_dir:
    parts.append(f"TensorBoard: {p.cfg.tensorboard_dir}")
  parts.append(f"checkpoint: {directory}")
  p.say("; ".join(parts))
  return Result(state, p.trainer, p.logger.rows, evaluation, p.evaluator.best,
                p.members.best_return)


def _header(cfg: RunConfig, trainer: train.Trainer, count: int, single: bool) -> str:
  config, each = trainer.config, "" if single else " each"
  per_chunk = config.steps_per_iteration * config.iterations_per_chunk
  return (f"{cfg.task_id} with {cfg.agent} ({cfg.agent_preset}): "
          f"{'' if single else f'{count} members, '}{config.num_envs} envs{each} on "
          f"{len(jax.local_devices())} {jax.local_devices()[0].platform} device(s), "
          f"{per_chunk:,} env steps and "
          f"{config.updates_per_iteration * config.iterations_per_chunk:,} updates per chunk"
          f"{'' if single else ' per member'}")


def _field_defaults(config) -> dict:
  """A config dataclass's fields' default values."""
  return {f.name: f.default for f in dataclasses.fields(config)
          if f.default is not dataclasses.MISSING}


def _progress_bar(total: int, initial: int):
  bar = tqdm(total=total, initial=min(initial, total), unit=" env steps", unit_scale=True,
             dynamic_ncols=True)
  bar.set_postfix_str("compiling the training step")
  return bar


def _above_progress_bars(print_fn: Callable[[str], None]) -> Callable[[str], None]:
  """`print_fn`, writing above any tqdm progress bar rather than into its line."""

  def say(line: str) -> None:
    with tqdm.external_write_mode():
      print_fn(line)
      sys.stdout.flush()
  return say


def __getattr__(name: str):
  return compat.moved(__name__, name)  # this module's old names


__all__ = ["Result", "RunConfig", "resume", "run"]
