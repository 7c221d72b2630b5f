"""The host loop: compiled training chunks, and between them the checks, logs, evaluations, PBT
steps, checkpoints and progress.

    from mjx_hopper import loop
    result = loop.run(loop.RunConfig(env="Hopper", agent="d4pg", total_env_steps=200_000))
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import math
import os
import sys
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from mjx_hopper import agents, checkpoint, parallel, pbt, runlock, sweep, train
from mjx_hopper.config import RunConfig
from mjx_hopper.evaluator import MAX_PENDING, Evaluator
from mjx_hopper.logger import Logger
from mjx_hopper.members import Members
from mjx_hopper.runs import build, check_which, init

ProgressFn = Callable[[int, dict], Any]


@dataclasses.dataclass
class Result:
  state: train.TrainState
  trainer: train.Trainer
  history: list[dict]            # every logged row (train and eval)
  evaluation: dict[str, Any]     # the final evaluation's per-episode arrays
  best: Any = None               # the agent at each member's best evaluation (None before any)
  best_return: Any = None        # (members,) those evaluations' mean returns

  def policy(self, which: str = "best", member: int = 0):
    """Member `member`'s agent state without the member axis: at its best evaluation (before
    any, the latest), or with which="latest", the latest."""
    check_which(which)
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
  say = _above_progress_bars(print_fn)
  with runlock.hold(_out_dir(cfg, process), say):
    parts, state = _open(cfg, checkpoint_dir, say, process, progress_fn)
    with checkpoint.StopRequest() as stop, parts.logger, _UserCode(parts, stop) as user:
      state = _train(parts, state, progress, stop)
    result = _finish(parts, state, stop)
  user.raise_error()
  return result


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


def _train(p: _Parts, state: train.TrainState, progress: bool, stop) -> train.TrainState:
  """Chunks until the run's end, a stop request, its deadline or its target."""
  cfg, members, evaluator = p.cfg, p.members, p.evaluator
  env_steps = p.env_steps(state)
  bar = _progress_bar(cfg.total_env_steps, env_steps) if progress and not p.until.reached(
      env_steps) else None
  next_eval = (env_steps // cfg.eval_every + 1) * cfg.eval_every
  pbt_period = cfg.eval_every * cfg.pbt.every if cfg.pbt else 0
  while not (p.until.reached(env_steps) or stop.requested or members.done()):
    before, t0 = env_steps, time.perf_counter()
    state, metrics = p.chunk(state)
    env_steps = p.env_steps(state)
    state = p.chunk.check(state, metrics, env_steps)
    rate = (env_steps - before) * len(members) / (time.perf_counter() - t0)
    _log_train(p, state, env_steps, rate, metrics)
    if members.all_diverged():
      break  # this state is not evaluated, and never saved
    last = p.until.reached(env_steps)
    due = env_steps >= next_eval or last
    if due:
      next_eval += cfg.eval_every
      evaluator.submit(env_steps, state.agent, members.diverged)
    # A run's last evaluation and PBT's (which needs the returns) wait; the others do not.
    _log_evaluations(p, evaluator.collect(members, wait=due and (last or bool(pbt_period))))
    if (due and pbt_period and env_steps // pbt_period > before // pbt_period
        and env_steps < cfg.total_env_steps):
      state = p.pbt_step(state, evaluator.latest["return"].mean(-1), env_steps, members)
    if p.saver.due():
      _log_evaluations(p, evaluator.collect(members, wait=True))  # a checkpoint holds them
      p.saver.save(state, evaluator.best, members)
    if bar is not None:
      bar.update(min(env_steps, cfg.total_env_steps) - bar.n)
      bar.set_postfix_str(p.display.status(rate, p.logger))
  _close(p, state, bar)
  return state


def _close(p: _Parts, state: train.TrainState, bar) -> None:
  """After the last chunk: the evaluations still due, the bar, the last checkpoint."""
  _log_evaluations(p, p.evaluator.collect(p.members, wait=True))
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
  trainer = build(cfg, len(mine))
  members = Members(mine, indices, single=len(everyone) == 1, pbt=cfg.pbt is not None,
                    target=cfg.stop_at_return, say=say)
  evaluator = Evaluator(trainer, mine, cfg.eval_episodes, cfg.evaluates_on_host())
  saved_config = {**cfg.to_json(), "member_indices": indices}
  per_iteration = trainer.config.steps_per_iteration
  saver = checkpoint.Saver(checkpoint.manager(checkpoint_dir, cfg.keep_checkpoints),
                           saved_config, cfg.checkpoint_minutes, per_iteration, say)
  chunk = None
  if (saver.mngr.latest_step() or 0) * per_iteration < cfg.total_env_steps:
    chunk = _compile(trainer, cfg, mine, evaluator)
  resumed = checkpoint.resume(
      saver.mngr, init(cfg, trainer, mine), saved_config, say,
      defaults={"agent_config": _field_defaults(cfg.agent_config()), "env_settings": {}})
  members.restore(resumed.record)
  evaluator.best = resumed.best
  with open(os.path.join(out_dir, "config.json"), "w") as f:  # once resuming is agreed
    json.dump(saved_config, f, indent=1)
  env_steps = train.iterations(resumed.state) * per_iteration
  if chunk is None and env_steps < cfg.total_env_steps:  # an older step was read
    chunk = _compile(trainer, cfg, mine, evaluator)
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


def _compile(trainer: train.Trainer, cfg: RunConfig, members: list[dict], evaluator):
  """The training chunk's compile, started in a thread (it is the user's first wait), and the
  evaluation's after it: evaluations due before that is compiled wait in its queue."""
  shapes = jax.tree.map(
      lambda sharding, part: jax.tree.map(
          lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding), part),
      trainer.shardings, jax.eval_shape(lambda: init(cfg, trainer, members)))
  lowered = trainer.train_chunk.lower(shapes)  # tracing holds Python's lock: before the pool
  pool = concurrent.futures.ThreadPoolExecutor(1)  # one program after the other
  chunk = pool.submit(lowered.compile)
  evaluator.compile_in(pool, shapes.agent)
  pool.shutdown(wait=False)
  return chunk


class _Chunk:
  """Runs one compiled chunk: (state, its metrics on the host); `check` then freezes a sweep's
  members that diverged in it at their agents before it."""

  def __init__(self, program, evaluator: Evaluator, members: Members):
    self.program, self.members = program, members
    self._copy, self._select = evaluator.copy_agents, evaluator.select_agents

  def __call__(self, state: train.TrainState):
    self.before = None if self.members.single else self._copy(state.agent)
    state, metrics = self.program.result()(state)
    return state, jax.device_get(metrics)

  def check(self, state: train.TrainState, metrics: dict, env_steps: int):
    """Marks the members that went non-finite in the chunk, and freezes them."""
    self.members.check(env_steps, metrics, jax.device_get(_finite_members(state.agent)))
    if self.before is not None and self.members.diverged.any():
      state = state._replace(agent=self._select(self.members.diverged, self.before,
                                                state.agent))
    return state


class _Until:
  """When the run ends: at its env steps, its deadline, or when progress_fn says so."""

  def __init__(self, cfg: RunConfig, t_start: float):
    self.t_start, self.total = t_start, cfg.total_env_steps
    self.deadline = t_start + 60 * cfg.max_minutes if cfg.max_minutes else math.inf

  def elapsed(self) -> float:
    return time.perf_counter() - self.t_start

  def stop(self) -> None:
    self.deadline = -math.inf

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


def _log_train(p: _Parts, state, env_steps: int, rate: float, metrics: dict) -> None:
  """A chunk's rows, one per member, and a sweep's terminal line."""
  updates = np.asarray(jax.device_get(state.updates))
  _log(p, env_steps, [{"kind": "train", **p.members.tags(m), "env_steps": env_steps,
                       "updates": int(updates[m]), "wall_s": p.until.elapsed(),
                       "steps_per_s": rate, **{k: float(v[m]) for k, v in metrics.items()}}
                      for m in range(len(p.members))])
  if not p.members.all_diverged():
    p.display.trained(env_steps, rate, metrics["episode_return"], p.cfg.log_every)


def _log_evaluations(p: _Parts, done: list[tuple[int, dict]]) -> None:
  """Each finished evaluation's rows, one per member, and a sweep's terminal line."""
  for env_steps, result in done:
    _log(p, env_steps, [{"kind": "eval", **p.members.tags(m), "env_steps": env_steps,
                         "wall_s": p.until.elapsed(),
                         "eval_return": float(np.mean(result["return"][m])),
                         "eval_return_std": float(np.std(result["return"][m])),
                         "eval_length": float(np.mean(result["length"][m]))}
                        for m in range(len(p.members))])
    p.display.evaluated(env_steps, result["return"].mean(-1))


def _log(p: _Parts, env_steps: int, rows: list[dict]) -> None:
  """Writes `rows` to the logger, then hands them to progress_fn: a False from it ends the
  run after this chunk's evaluation."""
  for row in rows:
    p.logger.write(row, force=row["kind"] == "eval")
  if p.progress_fn is not None:
    metrics = dict(rows[0]) if p.members.single else {
        k: rows[0][k] if k == "kind" else np.array([row[k] for row in rows]) for k in rows[0]}
    if p.progress_fn(env_steps, metrics) is False:
      p.until.stop()


def _finish(p: _Parts, state: train.TrainState, stop) -> Result:
  """The run's last lines (a sweep's ranking and curves first) and its Result."""
  evaluation = p.evaluator.latest
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


@jax.jit
def _finite_members(tree) -> jax.Array:
  """(members,): whether every float of each member's part of `tree` is finite."""
  checks = [jnp.isfinite(x).reshape(x.shape[0], -1).all(1) for x in jax.tree.leaves(tree)
            if jnp.issubdtype(x.dtype, jnp.floating) and x.size]
  return jnp.stack(checks).all(0)


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


join_processes = parallel.join_processes
from mjx_hopper.runs import extract, load_policy, restore, resume  # noqa: E402  (re-exports)

__all__ = ["MAX_PENDING", "Result", "RunConfig", "build", "extract", "init", "join_processes",
           "load_policy", "restore", "resume", "run"]
