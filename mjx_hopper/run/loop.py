"""The host loop: compiled training chunks, and between them the checks, logs, evaluations, PBT
steps, checkpoints and progress.

    from mjx_hopper.run import loop
    result = loop.run(loop.RunConfig(env="Hopper", agent="d4pg", total_env_steps=200_000))
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys
import time
from typing import Any, Callable, NamedTuple

import jax
import numpy as np
from tqdm.auto import tqdm

import mjx_hopper
from mjx_hopper import store
from mjx_hopper.core import evaluator as evaluation, start, train
from mjx_hopper.process import distributed, runlock
from mjx_hopper.process.stop import StopRequest
from mjx_hopper.run import checkpoints, opening
from mjx_hopper.run.logger import check_services
from mjx_hopper.run.opening import ProgressFn
from mjx_hopper.settings.config import RunConfig
from mjx_hopper.settings.plan import resolve
from mjx_hopper.store.run_folder import RunFolder


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
    checkpoints.check_which(which)
    agent = self.state.agent if which == "latest" or self.best is None else self.best
    return jax.tree.map(lambda x: x[member], agent)


def run(cfg: RunConfig, checkpoint_dir: str | None = None, progress: bool = True,
        print_fn=print, distributed_run: "bool | distributed.Cluster" = False,
        progress_fn: ProgressFn | None = None) -> Result:
  """Trains until `total_env_steps`, evaluating every `eval_every` env steps and at the end.

  Writes `out_dir`/log.csv, config.json and checkpoints (to `checkpoint_dir`, default
  `out_dir`/checkpoints); a run whose checkpoint_dir holds one resumes from it. Ctrl-C or
  SIGTERM saves after the chunk in flight. `progress_fn(env_steps, metrics)` is called after
  every chunk and every evaluation with log.csv's fields (a sweep's: one value per member);
  returning False ends the run as `max_minutes` does, and an exception from it (or from a
  logger's sink) ends it as Ctrl-C does, then is raised. With `distributed_run` (True: from the
  launcher's variables, or a `distributed.Cluster`) this process is one of several that train
  the members together over every process's devices (docs/sweeps.md); process 0 writes the
  files, says the lines and calls progress_fn. The run holds `out_dir`'s lock (`runlock`)
  throughout. It calls `mjx_hopper.setup()`: after JAX has started, XLA's flags stay as they were.
  """
  mjx_hopper.setup()
  if distributed_run:
    distributed.join(distributed_run)  # before anything runs on a device
  primary = distributed.primary()
  check_services(cfg.wandb, cfg.tensorboard_dir)  # before a compile, which exit waits for
  plan = resolve(cfg, processes=distributed.count(), backend=jax.default_backend())
  say = _above_progress_bars(print_fn) if primary else _silent
  folder = RunFolder(cfg.out_dir)
  with _lock(folder.path, say, primary), distributed.watch(folder.path):
    parts, restored = opening.open_run(plan, folder, checkpoint_dir, say,
                                       progress_fn if primary else None)
    with StopRequest() as stop, parts.logger, _naming_the_checkpoint_at_an_error(parts):
      user = _UserCode(stop)
      state = _train(parts, restored, progress, stop, user)
    result = _finish(parts, state, stop)
  user.raise_error()
  return result


def resume(directory: str, progress: bool = True, print_fn=print, env: Any = None,
           progress_fn: ProgressFn | None = None, **changes) -> Result:
  """Continues the run checkpointed in `directory` with its saved config. `changes` replace
  fields that may change between a run and its resumption (total_env_steps, max_minutes, ...);
  one the saved state depends on is refused, naming it. `env` is the run's task, for one that
  cannot be imported (defined in a notebook)."""
  cfg = checkpoints.built_here(checkpoints.saved_config(directory, print_fn, env), print_fn)
  return run(dataclasses.replace(cfg, **changes), checkpoint_dir=directory, progress=progress,
             print_fn=print_fn, progress_fn=progress_fn)


def _silent(line: str) -> None:
  """The lines of a process other than process 0, which says them."""


@contextlib.contextmanager
def _lock(folder: str, say, primary: bool):
  """Process 0 holds `folder`'s lock (`runlock.hold`); where it cannot, every process ends."""
  error = None
  with contextlib.ExitStack() as stack:
    if primary:
      try:
        stack.enter_context(runlock.hold(folder, say))
      except runlock.Locked as locked:
        error = locked
    refused, = distributed.agree("lock", error is not None)
    if error is not None:
      raise error
    if refused:
      raise runlock.Locked(f"process 0 could not take {folder}'s lock: another run holds it")
    yield


def _train(p: opening.Parts, restored: opening.Restored, progress: bool, stop,
           user: "_UserCode") -> train.TrainState:
  """Chunks from `restored` until the env steps or deadline, a stop, the target, or every
  member diverged."""
  cfg, members = p.cfg, p.members
  chunk = Chunk(p.started, p.evaluator, members)
  state, env_steps = restored.resumed.state, restored.env_steps
  bar = _progress_bar(p, env_steps) if progress else None
  next_eval = (env_steps // cfg.eval_every + 1) * cfg.eval_every
  asked = last = False  # asked by progress_fn; last: the run ends after this chunk
  while True:
    # What one process alone knows (a signal, its clock, progress_fn) is agreed on.
    stopped, signalled = distributed.agree(
        "chunk", asked or last or p.until.total_reached(env_steps), stop.requested)
    _signalled_elsewhere(stop, signalled)
    if stopped or signalled or members.done():
      break
    before = env_steps
    state, env_steps, rate, asked_now = _one_chunk(p, chunk, user, state, env_steps)
    asked |= asked_now
    if members.all_diverged():
      break  # this state is not evaluated, and never saved
    state = chunk.refill(state)  # after the row: its program may still be compiling
    pbt_now = _pbt_due(cfg, before, env_steps)
    last, signalled, saving, compiling = distributed.agree(
        "after the chunk", asked or p.until.reached(env_steps), stop.requested, p.saver.due(),
        p.evaluator.compiling())
    _signalled_elsewhere(stop, signalled)
    due = env_steps >= next_eval or last
    next_eval += cfg.eval_every if due else 0
    # The last evaluation, PBT's and a checkpoint's (which need the returns) wait; others not.
    asked |= _take_evaluations(p, user, last or pbt_now or saving, compiling,
                               due=(env_steps, state.agent) if due else None)
    if pbt_now:
      state = p.pbt_step(state, p.evaluator.latest.returns, env_steps, members)
    if saving:
      p.saver.save(state, p.evaluator.best, members)
    _show(bar, p, env_steps, rate)
  _close(p, user, state, bar)
  return state


class Ran(NamedTuple):
  """What a chunk leaves on the host, gathered from every process in one exchange: its metrics
  (each (members,)), whether each member's agent is finite, and each member's update count."""
  metrics: dict
  finite: np.ndarray
  updates: np.ndarray


class Chunk:
  """Runs one compiled chunk and the refill of its episode starts, and freezes a sweep's members
  that diverged in it at their agents before it."""

  def __init__(self, started: start.Started | None, evaluator: evaluation.Evaluator, members):
    self.program, self._refill, self._finite = (
        (started.chunk, started.refill, started.finite) if started else (None, None, None))
    self.single = members.single
    self._copy, self._select = evaluator.copy_agents, evaluator.select_agents

  def __call__(self, state: train.TrainState):
    """(state after the chunk, what it leaves on the host (`Ran`), a sweep's agents before it
    (None for a single run, which stops when it diverges))."""
    before = None if self.single else self._copy(state.agent)
    state, metrics = self.program.result()(state)
    finite = self._finite.result()(state.agent)
    ran = Ran(*distributed.gather((metrics, finite, state.updates), "chunk's results"))
    return state, ran, before

  def refill(self, state: train.TrainState) -> train.TrainState:
    """`state` with fresh episode starts for the next chunk."""
    return state._replace(env=self._refill.result()(state.env, np.False_))

  def freeze(self, state: train.TrainState, before, diverged: np.ndarray) -> train.TrainState:
    """`state` with the agents of the `diverged` members taken back to `before`."""
    if before is None or not diverged.any():
      return state
    return state._replace(agent=self._select(diverged, before, state.agent))


def _one_chunk(p: opening.Parts, chunk: Chunk, user: "_UserCode", state: train.TrainState,
               before: int):
  """A chunk from `before` env steps, checked, its diverged members frozen, and logged: (state,
  env steps, env steps/s, whether progress_fn asked to stop)."""
  t0 = time.perf_counter()
  state, ran, agents_before = chunk(state)
  env_steps = before + p.trainer.config.steps_per_chunk
  p.members.check(env_steps, ran.metrics, ran.finite)
  state = chunk.freeze(state, agents_before, p.members.diverged)
  rate = (env_steps - before) * len(p.members) / (time.perf_counter() - t0)
  return state, env_steps, rate, _log_train(p, user, ran, env_steps, rate)


def _pbt_due(cfg: RunConfig, before: int, env_steps: int) -> bool:
  """Whether PBT steps after the chunk from `before` to `env_steps`: at every `pbt.every`-th
  evaluation, but not at the run's end."""
  if cfg.pbt is None:
    return False
  period = cfg.eval_every * cfg.pbt.every
  return env_steps // period > before // period and env_steps < cfg.total_env_steps


def _take_evaluations(p: opening.Parts, user: "_UserCode", wait: bool, compiling: bool,
                      due: tuple | None = None) -> bool:
  """Queues the evaluation `due` (env steps, agents) if any, then records, keeps and logs the
  evaluations that are done (with `wait`, all of them; while the evaluation is `compiling`,
  none). Returns whether progress_fn asked to stop."""
  if due is not None:
    p.evaluator.submit(*due, p.members.diverged)
  asked = False
  for done in p.evaluator.take(wait, compiling):
    p.evaluator.keep(done, p.members.evaluated(done.env_steps, done.returns, done.diverged))
    asked |= _log_evaluation(p, user, done)
  return asked


def _signalled_elsewhere(stop, signalled: bool) -> None:
  """Where another process of the run was signalled, stops this one too, saying so."""
  if signalled and not stop.requested:
    stop.request("stopped by a signal to another process")


def _close(p: opening.Parts, user: "_UserCode", state: train.TrainState, bar) -> None:
  """After the last chunk: the evaluations still running, the bar, the last checkpoint."""
  _take_evaluations(p, user, wait=True, compiling=False)  # waiting, whatever it agreed
  if bar is not None:
    bar.close()
  if not p.members.all_diverged():
    p.saver.save(state, p.evaluator.best, p.members, last=True)
  p.saver.finish(state)


class _UserCode:
  """Calls the user's code between chunks (progress_fn, the logger's sinks) so that its first
  exception ends the run as Ctrl-C does: the chunk is finished and saved (unless its state is
  no longer finite), then `raise_error` raises it."""

  def __init__(self, stop: StopRequest):
    self.stop, self.error = stop, None

  def call(self, name: str, fn: Callable, *args, **kwargs):
    """`fn(*args, **kwargs)`; None where it raised."""
    try:
      return fn(*args, **kwargs)
    except Exception as error:  # noqa: BLE001 - raised once the state is saved
      if self.error is None:
        self.error = error
        self.stop.request(f"stopped by {name}'s {type(error).__name__}")

  def raise_error(self) -> None:
    if self.error is not None:
      raise self.error


@contextlib.contextmanager
def _naming_the_checkpoint_at_an_error(parts: opening.Parts):
  """Where an error leaves the loop (not a failed save, which names its own), waits for the save
  in flight and says which checkpoint resumes the run."""
  try:
    yield
  except (Exception, KeyboardInterrupt) as error:
    if not isinstance(error, store.SaveFailed):
      mngr = parts.saver.mngr
      try:
        store.wait_and_record(mngr)
        kept = mngr.latest_step()
        parts.say(f"the run stopped at an error: {mngr.directory} holds "
                  + (f"its checkpoint step {kept}, which resumes it" if kept is not None
                     else "no checkpoint of it"))
      except store.SaveFailed as failed:
        parts.say(f"the run stopped at an error; {failed}")
    raise


def _log_train(p: opening.Parts, user: _UserCode, ran: Ran, env_steps: int,
               rate: float) -> bool:
  """Logs a chunk: a row per member, and a sweep's terminal line. Returns whether progress_fn
  asked to stop."""
  metrics = ran.metrics
  rows = [{"kind": "train", **p.members.tags(m), "env_steps": env_steps,
           "updates": int(ran.updates[m]), "wall_s": p.until.elapsed(), "steps_per_s": rate,
           **{k: float(v[m]) for k, v in metrics.items()}} for m in range(len(p.members))]
  if not p.members.all_diverged():
    p.display.trained(env_steps, rate, metrics["episode_return"], p.cfg.log_every)
  return _log(p, user, env_steps, rows)


def _log_evaluation(p: opening.Parts, user: _UserCode, done) -> bool:
  """Logs a finished evaluation: a row per member, and a sweep's terminal line. Returns whether
  progress_fn asked to stop."""
  returns = done.result["return"]
  rows = [{"kind": "eval", **p.members.tags(m), "env_steps": done.env_steps,
           "wall_s": p.until.elapsed(), "eval_return": float(np.mean(returns[m])),
           "eval_return_std": float(np.std(returns[m])),
           "eval_length": float(np.mean(done.result["length"][m]))}
          for m in range(len(p.members))]
  p.display.evaluated(done.env_steps, done.returns)
  return _log(p, user, done.env_steps, rows)


def _log(p: opening.Parts, user: _UserCode, env_steps: int, rows: list[dict]) -> bool:
  """Writes `rows` to the logger, then hands them to progress_fn. Returns whether it returned
  False."""
  for row in rows:
    user.call("the logger", p.logger.write, row, force=row["kind"] == "eval")
  if p.progress_fn is None:
    return False
  metrics = dict(rows[0]) if p.members.single else {
      k: rows[0][k] if k == "kind" else np.array([row[k] for row in rows]) for k in rows[0]}
  return user.call("progress_fn", p.progress_fn, env_steps, metrics) is False


def _show(bar, p: opening.Parts, env_steps: int, rate: float) -> None:
  """Moves the progress bar (if any) to `env_steps`."""
  if bar is not None:
    bar.update(min(env_steps, p.cfg.total_env_steps) - bar.n)
    bar.set_postfix_str(p.display.status(rate, p.logger))


def _finish(p: opening.Parts, state: train.TrainState, stop) -> Result:
  """The run's last lines (a sweep's ranking and curves first) and its Result."""
  evaluation = None if p.evaluator.latest is None else p.evaluator.latest.result
  if p.members.single and evaluation is not None:
    evaluation = jax.tree.map(lambda x: x[0], evaluation)  # a single run is one member
  folder = p.folder
  if distributed.primary():
    p.display.summarise(p.logger.rows, folder.path)
  directory = p.saver.mngr.directory
  if p.members.all_diverged():
    kept = p.saver.mngr.latest_step()
    p.say("training diverged; nothing was saved after it: "
          + (f"the last finite checkpoint is step {kept} in {directory}, which loop.resume "
             "continues (a lower learning rate may avoid it)" if kept is not None
             else "no checkpoint was saved before it"))
  why = stop.reason if stop.requested else p.members.outcome()
  parts = [f"{why}: {p.trainer.env_steps(state):,} env steps in {p.until.elapsed():.0f} s"]
  if p.members.single and evaluation is not None:
    parts.append(f"evaluation return {np.mean(evaluation['return']):.1f} over "
                 f"{len(evaluation['return'])} episodes")
  parts.append(f"log: {folder.log}")
  if p.cfg.tensorboard_dir:
    parts.append(f"TensorBoard: {p.cfg.tensorboard_dir}")
  parts.append(f"checkpoint: {directory}")
  p.say("; ".join(parts))
  return Result(state, p.trainer, p.logger.rows, evaluation, p.evaluator.best,
                p.members.best_return)


def _progress_bar(p: opening.Parts, initial: int):
  """The run's progress bar from `initial` env steps; None where it trains no further."""
  total = p.cfg.total_env_steps
  if p.until.total_reached(initial):
    return None
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


__all__ = ["Result", "RunConfig", "resume", "run"]
