"""Saving a run as it trains (`Saver`), and reading it back (`read_latest`) from the newest step
that reads, falling back to older ones."""

from __future__ import annotations

import json
import time
from typing import TYPE_CHECKING, Any, NamedTuple

from mjx_hopper.core import train
from mjx_hopper.process import errors
from mjx_hopper.settings.config import MUST_MATCH
from mjx_hopper.store.failures import SaveFailed, quiet_failed_saves
from mjx_hopper.store.items import ConfigMismatch, read_best, read_config, read_state, save
from mjx_hopper.store.manifests import damage, wait_and_record

if TYPE_CHECKING:  # orbax is imported where a checkpoint is first opened (store.items)
  import orbax.checkpoint as ocp


def load_newest(mngr: ocp.CheckpointManager, load, print_fn=print):
  """(step, load(step)) for the newest step that `load` succeeds on. Each newer step that
  fails is skipped with a warning naming its error; a ConfigMismatch is raised at once."""
  steps = sorted(mngr.all_steps(), reverse=True)
  for step in steps:
    try:
      return step, load(step)
    except ConfigMismatch:
      raise
    except Exception as error:  # noqa: BLE001 - any unreadable step falls back to the previous
      why = "; ".join(damage(mngr, step)) or _why(error)
      print_fn(f"WARNING: checkpoint step {step} in {mngr.directory} is unreadable ({why}); "
               "trying an older one")
  raise ValueError(f"no readable checkpoint in {mngr.directory} (steps {steps}); nothing was "
                   "overwritten: move it aside to start afresh")


def _why(error: Exception) -> str:
  text = errors.first_line(error, typed=True)
  if "tree structures do not match" in str(error):
    text = ("its training state is laid out otherwise than this version of mjx_hopper's, "
            "perhaps saved by an older one; " + text)
  return text


class Resumed(NamedTuple):
  """What `read_latest` read: the state, its step (None for a fresh run), the agent at the best
  evaluations (None when the step has none) and the members' record ({} when none)."""

  state: train.TrainState
  step: int | None
  best: Any
  record: dict


def read_latest(mngr: ocp.CheckpointManager, fresh: train.TrainState, config: dict,
           print_fn=print, defaults: dict | None = None) -> Resumed:
  """The latest readable checkpoint's state, best agents and record (`Resumed`), or `fresh`
  when there is none.

  Falls back to older steps, with a warning naming the error, when the newest cannot be read.
  A checkpoint of another config is a ConfigMismatch (a ValueError) naming the settings that
  differ. `defaults` ({config key: {setting: value}}) are the values that a setting missing
  from a saved config's dict had: an older version, which lacked the setting, ran as its default
  (such as the agents' `compute_dtype`, "float32").
  """
  if not mngr.all_steps():
    print_fn(f"no checkpoint in {mngr.directory}: starting a fresh run")
    return Resumed(fresh, None, None, {})

  def load(step):
    saved = _matching(read_config(mngr, step), config, defaults, mngr.directory)
    return (read_state(mngr, step, fresh), read_best(mngr, step, fresh.agent),
            saved.get("record", {}))

  step, (state, best, record) = load_newest(mngr, load, print_fn)
  print_fn(f"resumed from {mngr.directory}, step {step}")
  return Resumed(state, step, best, record)


def check_config(mngr: ocp.CheckpointManager, config: dict, defaults: dict | None = None
                 ) -> None:
  """A ConfigMismatch, as `read_latest` raises it, where the newest checkpoint whose config
  reads is of another config: checked before anything is compiled for a run that would be
  refused. A step whose config does not read is left to `read_latest`."""
  for step in sorted(mngr.all_steps(), reverse=True):
    try:
      saved = read_config(mngr, step)
    except ConfigMismatch:
      raise
    except Exception:  # noqa: BLE001 - read_latest names what is wrong with it
      continue
    _matching(saved, config, defaults, mngr.directory)
    return


def _matching(saved: dict, config: dict, defaults: dict | None, directory) -> dict:
  """`saved` (a config item), with `defaults` ({config key: {setting: value}}) filled in where
  an older version lacked a setting, once its settings in MUST_MATCH are `config`'s; else a
  ConfigMismatch naming those that differ."""
  config = json.loads(json.dumps(config))  # as saved: tuples become lists
  for key, values in json.loads(json.dumps(defaults or {})).items():
    if isinstance(saved.get(key, {}), dict):
      saved[key] = {**values, **saved.get(key, {})}
  differ = [k for k in MUST_MATCH if saved.get(k) != config.get(k)]
  if differ:
    details = "; ".join(f"{k}: saved {saved.get(k)!r}, now {config.get(k)!r}" for k in differ)
    raise ConfigMismatch(f"the checkpoint in {directory} is from another config ({details}); "
                         "use another checkpoint directory, or the saved settings")
  return saved


class Saver:
  """A run's checkpoints: every `minutes`, and its last one, each with the run's `config` and
  its members' record.

  A save that fails (a full disk, no permission, a vanished mount) or cannot fit loses nothing
  that was saved: it is said in one line (where, why, and the env steps not saved since the
  last good checkpoint), its partial files are removed, and training goes on: the next save
  tries again (said once). The run's last save is its last chance: `finish` raises its failure
  as a SaveFailed, which ends the run.
  """

  def __init__(self, mngr: ocp.CheckpointManager, config: dict, minutes: float,
               steps_per_iteration: int, say=print):
    quiet_failed_saves()
    self.mngr, self.config, self.minutes = mngr, config, minutes
    self.per_iteration, self.say = steps_per_iteration, say
    self.last = time.monotonic()
    self.pending = None   # the step being saved
    self.failures = 0     # saves that failed since the last that worked
    self.unsaved = None   # the run's last save's SaveFailed, which `finish` raises

  def due(self) -> bool:
    """Whether the save period has passed since the last save."""
    return time.monotonic() - self.last >= 60 * self.minutes

  def save(self, state: train.TrainState, best, members, last: bool = False) -> None:
    """Starts saving `state`, `best` (the agents at their best evaluations) and `members`'
    record, once the previous save has finished. Saving the run's `last` state, a failure is
    kept for `finish`."""
    failed = self._wait()
    if failed is not None:
      self._report(failed, state)
    try:
      self.pending = save(self.mngr, state, {**self.config, "record": members.record()},
                          best=best)
    except SaveFailed as error:
      if last:
        self.unsaved = error
      else:
        self._report(error, state)
    self.last = time.monotonic()

  def finish(self, state: train.TrainState) -> None:
    """Waits for the save in flight; a SaveFailed naming what is lost if the last one failed."""
    failed = self.unsaved or self._wait()
    self.unsaved = None
    if failed is not None:
      raise self._lost(failed, state) from None

  def _wait(self) -> SaveFailed | None:
    """The failure of the save in flight, once it ends; where it works after failures, says
    so."""
    step, self.pending = self.pending, None
    try:
      wait_and_record(self.mngr)
    except SaveFailed as error:
      return error
    if step is not None and self.failures:
      self.say(f"checkpoint step {step} is saved in {self.mngr.directory}, after "
               f"{self.failures} failed save(s)")
      self.failures = 0
    return None

  def _report(self, error: SaveFailed, state: train.TrainState) -> None:
    then = "" if self.failures else (
        f"; training goes on, and the next save tries again in {self.minutes:g} min")
    self.failures += 1
    self.say(f"WARNING: {self._lost(error, state)}{then}")

  def _lost(self, error: SaveFailed, state: train.TrainState) -> SaveFailed:
    """`error`, saying how many env steps of `state` are not saved since the newest good
    checkpoint."""
    steps = (train.iterations(state) - (error.last_good or 0)) * self.per_iteration
    since = ("(no checkpoint of this run is saved)" if error.last_good is None else
             f"since step {error.last_good}, which is intact")
    return SaveFailed(error.directory, error.step, error.reason, error.last_good,
                      f"{steps:,} env steps are not saved {since}")
