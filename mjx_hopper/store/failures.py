"""A save that fails (a full disk, no permission, a vanished mount) or would not fit: its
SaveFailed, the clean-up of its partial files, and quiet logs of it."""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import re
import shutil
import sys
import threading
import time
from typing import TYPE_CHECKING

import jax

from mjx_hopper.process import errors

if TYPE_CHECKING:  # orbax is imported where a checkpoint is first opened (store.items)
  import orbax.checkpoint as ocp


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


def check_space(mngr: ocp.CheckpointManager, step: int, tree) -> None:
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


ORBAX_COMMIT_THREAD = "async_save"  # the name of orbax's background commit thread, a plain Thread


def _orbax_writer(thread: threading.Thread) -> bool:
  """Whether `thread` writes a step for orbax: one of its own Thread classes, or its background
  commit thread, which stores its error to raise at the next save (a failed save's other item
  can fail there after the first error was raised)."""
  return type(thread).__module__.startswith("orbax.") or thread.name == ORBAX_COMMIT_THREAD


def failed(mngr: ocp.CheckpointManager, step: int | None, error: Exception) -> SaveFailed:
  """The SaveFailed of a save of `step` (None: the one in flight) that raised `error`, after
  removing the step's partial files, which would otherwise confuse the next resume. Orbax's
  other writer threads of the step may still be writing: they are waited for first."""
  for thread in threading.enumerate():
    if _orbax_writer(thread) and thread is not threading.current_thread():
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
  return errors.first_line(error, typed=True)


_quieted = False


def quiet_failed_saves() -> None:
  """Leaves a failed save to SaveFailed's one line: drops orbax's logged tracebacks of it,
  asyncio's "Future exception was never retrieved" for its writes, and what its writer threads
  and coroutines raise after it. Once per process: each `Saver` calls it."""
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
