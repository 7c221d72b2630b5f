"""Orbax checkpoints of the whole TrainState, beside a JSON item with the run's config.

A checkpoint step holds up to four items: "agent" (the agent's pytree: params, targets,
optimizer states), "trainer" (replay, env states, keys, counters), "best" (the agent's pytree
at each member's best evaluation so far, once there is one) and "config" (JSON: the RunConfig,
env, agent, package versions, the checkpoint's format version, and the run's `record` of its
members: their best evaluations, divergence and, under PBT, lineage). Keeping the agent apart lets
`restore_agent` load a policy without reading the replay.

A save that fails (a full disk, no permission, a vanished mount) is a SaveFailed: its partial
files are removed and every earlier step is left as it was. `Saver` holds a run's policy for it.
"""

from __future__ import annotations

import contextlib
import errno
import importlib.metadata
import json
import logging
import os
import re
import shutil
import signal
import sys
import threading
import time
import zlib
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import orbax.checkpoint as ocp

import mjx_hopper
from mjx_hopper import parallel, train

# The layout of the saved items. Every change to it raises FORMAT (CHANGELOG.md says so), and
# OLDEST_FORMAT is the oldest layout this version still reads. Checkpoints saved before formats
# were recorded have today's layout: they count as format 1.
FORMAT = 1
OLDEST_FORMAT = 1


class ConfigMismatch(ValueError):
  """A checkpoint saved by another config."""


class FormatMismatch(ConfigMismatch):
  """A checkpoint whose layout this version cannot read (an older or a newer format)."""


class SaveFailed(ValueError):
  """A checkpoint step that could not be written, or would not fit. Its partial files are
  removed; `last_good`, the newest step saved before it (None: none), is intact. `lost` says
  what that leaves unsaved (by default, which step is intact)."""

  def __init__(self, directory: str, step: int | None, reason: str, last_good: int | None,
               lost: str | None = None):
    self.directory, self.step, self.reason, self.last_good = directory, step, reason, last_good
    lost = lost or ("no step is saved there" if last_good is None
                    else f"step {last_good}, saved before it, is intact")
    super().__init__(f"checkpoint step {step} was not saved in {directory}: {reason}; {lost}")


PACKAGES = ("mjx_hopper", "jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax",
            "orbax-checkpoint", "brax")


def versions() -> dict[str, str]:
  """The versions of mjx_hopper (its own, not an editable install's metadata) and of the
  packages it runs on."""
  out = {"mjx_hopper": mjx_hopper.__version__}
  for name in PACKAGES[1:]:
    try:
      out[name] = importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
      out[name] = "not installed"
  return out


def manager(directory: str, max_to_keep: int = 3) -> ocp.CheckpointManager:
  """A CheckpointManager over `directory` (created if missing), saving asynchronously."""
  _quiet_failed_saves()
  options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep,
                                         enable_async_checkpointing=True)
  return ocp.CheckpointManager(os.path.abspath(directory), options=options,
                               item_names=("agent", "trainer", "best", "config"))


def _split(state: train.TrainState) -> tuple:
  trainer = {k: v for k, v in state._asdict().items() if k != "agent"}
  return state.agent, trainer


def _nonempty(tree) -> dict:
  """The leaves of `tree` by index, leaving out zero-size ones (orbax cannot write them; MJX's
  Data has some, such as `act` for models without actuator states)."""
  return {str(i): x for i, x in enumerate(jax.tree.leaves(tree)) if x.size}


def _rebuild(like, saved: dict):
  """`like`'s structure with the saved leaves, placed as `like`'s, and its zero-size leaves
  as empty arrays."""
  leaves, treedef = jax.tree.flatten(like)
  return treedef.unflatten([jax.device_put(saved[str(i)] if str(i) in saved
                                           else jnp.zeros(x.shape, x.dtype), x.sharding)
                            for i, x in enumerate(leaves)])


MANIFESTS = "manifests"  # beside the steps: the files of each finished step, with sizes and CRCs


def _files(step_dir: str) -> dict[str, tuple[int, int]]:
  """{relative path: (size, crc32)} of every file under `step_dir`."""
  out = {}
  for root, _, names in os.walk(step_dir):
    for name in names:
      path = os.path.join(root, name)
      with open(path, "rb") as f:
        out[os.path.relpath(path, step_dir)] = (os.path.getsize(path), zlib.crc32(f.read()))
  return out


def finish(mngr: ocp.CheckpointManager) -> None:
  """Waits for the save in flight, then records the files of every finished step that has no
  manifest yet (and drops the manifests of steps that are gone), so that a damaged step can be
  told apart file by file later. A save that failed is a SaveFailed (see `_failed`)."""
  try:
    mngr.wait_until_finished()
    _write_manifests(mngr)
  except Exception as error:  # noqa: BLE001 - orbax and tensorstore wrap OSErrors in their own
    raise _failed(mngr, None, error) from None


def _write_manifests(mngr: ocp.CheckpointManager) -> None:
  folder = os.path.join(mngr.directory, MANIFESTS)
  steps = {str(step) for step in mngr.all_steps()}
  if not steps and not os.path.isdir(folder):
    return
  os.makedirs(folder, exist_ok=True)
  for name in os.listdir(folder):
    if name.removesuffix(".json") not in steps:
      os.remove(os.path.join(folder, name))
  for step in steps - {n.removesuffix(".json") for n in os.listdir(folder)}:
    path = os.path.join(folder, f"{step}.json")
    with open(path + ".tmp", "w") as f:
      json.dump(_files(os.path.join(mngr.directory, step)), f)
    os.replace(path + ".tmp", path)


def damage(mngr: ocp.CheckpointManager, step: int) -> list[str]:
  """How `step`'s files differ from its manifest: one line per missing, truncated or changed
  file (empty when they match, or when the step has no manifest)."""
  path = os.path.join(mngr.directory, MANIFESTS, f"{step}.json")
  if not os.path.exists(path):
    return []
  with open(path) as f:
    saved = json.load(f)
  step_dir = os.path.join(mngr.directory, str(step))
  now = _files(step_dir)
  out = []
  for name, (size, crc) in sorted(saved.items()):
    file = os.path.join(step_dir, name)
    if name not in now:
      out.append(f"{file} is missing")
    elif now[name][0] != size:
      out.append(f"{file} has {now[name][0]:,} bytes, {size:,} when saved")
    elif now[name][1] != crc:
      out.append(f"{file} has changed since it was saved (CRC32)")
  return out


def save(mngr: ocp.CheckpointManager, state: train.TrainState, config: dict,
         best=None) -> int:
  """Starts saving `state` (and `best`, the agent's pytree at its best evaluations, when given)
  as step = its iteration count, after finishing the previous save (see `finish`); returns the
  step. Call `finish(mngr)` before relying on it. A SaveFailed where the previous save failed,
  or where this one cannot fit on the disk (checked before anything is written) or start."""
  finish(mngr)
  step = train.iterations(state)
  _check_space(mngr, step, (state, best))
  agent, trainer = _split(state)
  items = dict(agent=ocp.args.StandardSave(_nonempty(agent)),
               trainer=ocp.args.StandardSave(_nonempty(trainer)),
               config=ocp.args.JsonSave({**config, "versions": versions(),
                                         "checkpoint_format": FORMAT}))
  if best is not None:
    items["best"] = ocp.args.StandardSave(_nonempty(best))
  try:
    mngr.save(step, args=ocp.args.Composite(**items))
  except Exception as error:  # noqa: BLE001 - as in `finish`
    raise _failed(mngr, step, error) from None
  return step


def _check_space(mngr: ocp.CheckpointManager, step: int, tree) -> None:
  """A SaveFailed when the disk of `mngr`'s folder (where its free space can be read) has less
  room than a step takes: as much as the newest step, else the arrays' own bytes."""
  newest = mngr.latest_step()
  needed = (_disk_bytes(os.path.join(mngr.directory, str(newest))) if newest is not None
            else sum(x.nbytes for x in jax.tree.leaves(tree)))
  try:
    free = shutil.disk_usage(mngr.directory).free
  except OSError:
    return  # the save itself finds out
  if free < needed:
    raise SaveFailed(mngr.directory, step, f"a step takes about {_size(needed)} and its disk "
                     f"has {_size(free)} free (nothing was written)", newest)


def _disk_bytes(folder: str) -> int:
  return sum(os.path.getsize(os.path.join(root, name))
             for root, _, names in os.walk(folder) for name in names)


def _size(n: int) -> str:
  for unit, scale in (("GB", 1e9), ("MB", 1e6)):
    if n >= scale:
      return f"{n / scale:,.1f} {unit}"
  return f"{n / 1e3:,.0f} kB"


PARTIAL = ".orbax-checkpoint-tmp"  # in the names of orbax's folders of unfinished steps
WRITERS_S = 60.0  # how long a failed save's other writer threads are waited for, each
QUIET_S = 1.0  # how long a failed save's folder must stay removed to count as gone


def _partial(directory: str) -> list[str]:
  """The names of orbax's unfinished steps in `directory` (none where it cannot be read)."""
  try:
    return [name for name in os.listdir(directory) if PARTIAL in name]
  except OSError:  # a vanished mount
    return []


def _failed(mngr: ocp.CheckpointManager, step: int | None, error: Exception) -> SaveFailed:
  """The SaveFailed of a save of `step` (None: the one in flight) that raised `error`, after
  removing the step's partial files, which would otherwise confuse the next resume. Orbax's
  other writer threads of the step may still be writing: they are waited for first."""
  for thread in threading.enumerate():
    if type(thread).__module__.startswith("orbax.") and thread is not threading.current_thread():
      with contextlib.suppress(Exception):  # orbax's threads raise their error again on join
        thread.join(WRITERS_S)
  with contextlib.suppress(Exception):  # orbax keeps the error to raise at the next save
    mngr.check_for_errors()
  # Tensorstore's writes of the step go on in threads of its own, which can recreate a removed
  # folder: the partial folders are removed until none has come back for QUIET_S.
  deadline = time.monotonic() + WRITERS_S
  quiet_since = time.monotonic()
  while time.monotonic() - quiet_since < QUIET_S and time.monotonic() < deadline:
    for name in _partial(mngr.directory):
      if step is None and name.split(".")[0].isdigit():
        step = int(name.split(".")[0])
      shutil.rmtree(os.path.join(mngr.directory, name), ignore_errors=True)
      quiet_since = time.monotonic()
    time.sleep(QUIET_S / 20)
  steps = [s for s in mngr.all_steps() if s != step]
  return SaveFailed(mngr.directory, step, _reason(error), max(steps) if steps else None)


_OS_ERROR_CODE = re.compile(r"os_error_code='?(\d+)")  # how tensorstore reports an OSError


def _reason(error: BaseException) -> str:
  """Why a write failed, in a few words: the OS error found in `error` or its causes ("No space
  left on device (ENOSPC)"), else `error`'s first line."""
  cause = error
  while cause is not None:
    match = _OS_ERROR_CODE.search(str(cause))
    code = cause.errno if isinstance(cause, OSError) else int(match.group(1)) if match else None
    if code:
      return f"{os.strerror(code)} ({errno.errorcode.get(code, code)})"
    cause = cause.__cause__ or cause.__context__
  return f"{type(error).__name__}: {_first_line(error)}"


_quieted = False


def _quiet_failed_saves() -> None:
  """Leaves a failed save to SaveFailed's one line: drops orbax's logged tracebacks of it,
  asyncio's "Future exception was never retrieved" for its writes, and what its writer threads
  and coroutines raise after it. Once per process."""
  global _quieted
  if _quieted:
    return
  _quieted = True
  logging.getLogger("absl").addFilter(_not_a_failed_save)
  logging.getLogger("asyncio").addFilter(_not_a_failed_save)
  hook = sys.unraisablehook

  def unraisable(info):
    if not _orbax_leftover(info.exc_value, info.object):
      hook(info)
  sys.unraisablehook = unraisable


def _not_a_failed_save(record: logging.LogRecord) -> bool:
  """False for orbax's (absl's) logged tracebacks and asyncio's unretrieved errors of a save."""
  message = record.getMessage()
  if record.name == "absl":
    return not (record.exc_info and (message.startswith("[process=") or PARTIAL in message))
  return not ("exception was never retrieved" in message.split("\n")[0]
              and (PARTIAL in message or f"{os.sep}orbax{os.sep}" in message))


def _orbax_leftover(error: BaseException | None, source) -> bool:
  """Whether an error that Python could not raise is a failed save's: an orbax writer thread
  calling back into its closed event loop, or an orbax coroutine left unfinished."""
  code = getattr(source, "cr_code", None)
  return ((isinstance(error, RuntimeError) and str(error) == "Event loop is closed")
          or (code is not None and f"{os.sep}orbax{os.sep}" in code.co_filename))


def _abstract(tree):
  """Shapes, dtypes and placements to restore into (replicated where none is set)."""
  replicated = jax.sharding.NamedSharding(parallel.mesh(jax.local_devices(), ("d",)),
                                          jax.sharding.PartitionSpec())

  def one(x):
    sharding = getattr(x, "sharding", None) or replicated
    return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding)
  return jax.tree.map(one, tree)


def restore(mngr: ocp.CheckpointManager, step: int, like: train.TrainState) -> train.TrainState:
  """The TrainState saved at `step`, placed like `like` (a state or its abstract shapes)."""
  agent, trainer = _abstract(_split(like))
  out = mngr.restore(step, args=ocp.args.Composite(
      agent=ocp.args.StandardRestore(_nonempty(agent)),
      trainer=ocp.args.StandardRestore(_nonempty(trainer))))
  return train.TrainState(agent=_rebuild(agent, out.agent), **_rebuild(trainer, out.trainer))


def read_config(mngr: ocp.CheckpointManager, step: int) -> dict:
  """The config item saved at `step`; a FormatMismatch when this version cannot read its
  layout."""
  saved = mngr.restore(step, args=ocp.args.Composite(config=ocp.args.JsonRestore())).config
  check_format(saved, mngr.directory)
  return saved


def check_format(saved: dict, directory: str) -> None:
  """Raises a FormatMismatch naming both format versions when the checkpoint format recorded in
  `saved` (a config item; 1 where none is) is not one this version reads."""
  found = saved.get("checkpoint_format", 1)
  if OLDEST_FORMAT <= found <= FORMAT:
    return
  by = saved.get("versions", {}).get("mjx_hopper", "another version")
  reads = (f"format {FORMAT}" if OLDEST_FORMAT == FORMAT
           else f"formats {OLDEST_FORMAT} to {FORMAT}")
  todo = (f"use mjx_hopper {by} or newer" if found > FORMAT else
          f"use mjx_hopper {by} to resume or evaluate it, or to export its policy")
  raise FormatMismatch(f"the checkpoint in {directory} has format {found} (saved by mjx_hopper "
                       f"{by}), and mjx_hopper {mjx_hopper.__version__} reads {reads}: {todo}; "
                       "nothing was written")


def has_best(mngr: ocp.CheckpointManager, step: int) -> bool:
  """Whether `step` holds the agent at its best evaluations (steps saved before any
  evaluation, or by older versions, do not)."""
  return os.path.isdir(os.path.join(mngr.directory, str(step), "best"))


def restore_agent(mngr: ocp.CheckpointManager, step: int, like_agent, item: str = "agent"):
  """Only the agent's pytree saved at `step` (no replay is read): the latest ("agent") or the
  one of the best evaluations ("best")."""
  like_agent = _abstract(like_agent)
  saved = mngr.restore(step, args=ocp.args.Composite(
      **{item: ocp.args.StandardRestore(_nonempty(like_agent))}))[item]
  return _rebuild(like_agent, saved)


def restore_best(mngr: ocp.CheckpointManager, step: int, like_agent):
  """The agent at the best evaluations saved at `step`, or None where the step holds none."""
  return restore_agent(mngr, step, like_agent, "best") if has_best(mngr, step) else None


# The settings a checkpoint's state depends on; the others (run length, logging, evaluation)
# may change between a run and its resumption.
MUST_MATCH = ("env", "env_settings", "agent", "agent_config", "train", "episode_steps", "seed",
              "seeds", "grid", "pbt", "member_indices")


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
  text = f"{type(error).__name__}: {_first_line(error)}"
  if "tree structures do not match" in str(error):
    text = ("its training state is laid out otherwise than this version of mjx_hopper's, "
            "perhaps saved by an older one; " + text)
  return text


def _first_line(error: Exception, limit: int = 300) -> str:
  text = str(error).strip().splitlines()[0] if str(error).strip() else ""
  return text[:limit]


class Resumed(NamedTuple):
  """What `resume` read: the state, its step (None for a fresh run), the agent at the best
  evaluations (None when the step has none) and the members' record ({} when none)."""

  state: train.TrainState
  step: int | None
  best: Any
  record: dict


def resume(mngr: ocp.CheckpointManager, fresh: train.TrainState, config: dict,
           print_fn=print, defaults: dict | None = None) -> Resumed:
  """The latest readable checkpoint's state, best agents and record (`Resumed`), or `fresh`
  when there is none.

  Falls back to older steps, with a warning naming the error, when the newest cannot be read.
  A checkpoint of another config is a ConfigMismatch (a ValueError) naming the settings that
  differ. `defaults` ({config key: {setting: value}}) are the values that a setting missing
  from a saved config's dict had: an older version, which lacked the setting, ran as its default
  (such as the agents' `compute_dtype`, "float32").
  """
  config = json.loads(json.dumps(config))  # as saved: tuples become lists
  defaults = json.loads(json.dumps(defaults or {}))
  if not mngr.all_steps():
    print_fn(f"no checkpoint in {mngr.directory}: starting a fresh run")
    return Resumed(fresh, None, None, {})

  def load(step):
    saved = read_config(mngr, step)
    for key, values in defaults.items():
      if isinstance(saved.get(key, {}), dict):
        saved[key] = {**values, **saved.get(key, {})}
    differ = [k for k in MUST_MATCH if saved.get(k) != config.get(k)]
    if differ:
      details = "; ".join(f"{k}: saved {saved.get(k)!r}, now {config.get(k)!r}" for k in differ)
      raise ConfigMismatch(f"the checkpoint in {mngr.directory} is from another config "
                           f"({details}); use another checkpoint directory, or the saved "
                           "settings")
    return (restore(mngr, step, fresh), restore_best(mngr, step, fresh.agent),
            saved.get("record", {}))

  step, (state, best, record) = load_newest(mngr, load, print_fn)
  print_fn(f"resumed from {mngr.directory}, step {step}")
  return Resumed(state, step, best, record)


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
      finish(self.mngr)
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


class StopRequest:
  """Within `with`, Ctrl-C and SIGTERM set `requested` instead of stopping the process, so the
  loop can finish its chunk and save; a second Ctrl-C stops at once. `request` does the same
  from code, with the reason the run's last line gives."""

  def __enter__(self):
    self.requested, self.reason = False, "stopped by a signal"
    self._previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
      try:
        self._previous[sig] = signal.signal(sig, self._handle)
      except ValueError:  # not the main thread: signals stay as they are
        pass
    return self

  def request(self, reason: str) -> None:
    """Asks the loop to save and stop after its chunk, for `reason`."""
    self.requested, self.reason = True, reason

  def _handle(self, signum, frame):
    if self.requested and signum == signal.SIGINT:
      raise KeyboardInterrupt
    self.requested = True
    print(f"\n{signal.Signals(signum).name}: saving a checkpoint after this chunk",
          flush=True)

  def __exit__(self, *exc):
    for sig, handler in self._previous.items():
      signal.signal(sig, handler)
    return False
