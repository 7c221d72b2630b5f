"""One writer per run folder: a lock file naming the run that trains in it.

    with runlock.hold("runs/train"):
      ...   # train; another run on runs/train is refused, naming this one

The lock, `FOLDER/run.lock`, is JSON: the holder's host, process id, start and heartbeat
times. A thread refreshes the heartbeat every `HEARTBEAT_S` seconds, also while a program
compiles or an evaluation runs. A run finding a live holder's lock is refused in one line. A
lock is taken over, with one line, when its process has ended (on this host) or its heartbeat is
older than `STALE_S` (its host may be another: a folder on Google Drive). Reading a run (eval,
export, extract, plot) takes no lock.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import threading
import time
import uuid

LOCK = "run.lock"
HEARTBEAT_S = 60.0
STALE_S = 600.0  # ten heartbeats missed

_held: set[str] = set()  # the locks this process holds


class Locked(ValueError):
  """A run folder that another live run holds."""


@contextlib.contextmanager
def hold(folder: str, say=print):
  """Holds `folder`'s lock (the folder is made if missing) while in `with`, refreshing its
  heartbeat; a Locked error where another live run holds it."""
  os.makedirs(folder, exist_ok=True)
  path = os.path.abspath(os.path.join(folder, LOCK))
  mine = _take(path, say)
  _held.add(path)
  stop = threading.Event()
  beat = threading.Thread(target=_beat, args=(path, mine, stop), daemon=True,
                          name="mjx_hopper run lock")
  beat.start()
  try:
    yield path
  finally:
    stop.set()
    beat.join(timeout=10)  # (a daemon: a write stuck on a lost mount does not hold the exit)
    _held.discard(path)
    if _read(path).get("token") == mine["token"]:
      with contextlib.suppress(OSError):  # an error here would hide the run's own
        os.remove(path)


def _take(path: str, say) -> dict:
  """Creates the lock at `path`, or takes over a stale one; returns what it holds."""
  mine = {"host": socket.gethostname(), "pid": os.getpid(), "token": uuid.uuid4().hex,
          "started": time.time(), "heartbeat": time.time()}
  if not _create(path, mine):
    found = _read(path)
    why = _stale(path, found)
    if why is None:
      raise Locked(_refusal(path, found))
    say(f"taking over {path} from {_who(found)}, which {why}")
    with contextlib.suppress(FileNotFoundError):
      os.remove(path)
    if not _create(path, mine):  # another run took it over first
      raise Locked(_refusal(path, _read(path)))
  return mine


def _create(path: str, content: dict) -> bool:
  """Writes `content` to a new file at `path`; False where the file exists."""
  try:
    fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
  except FileExistsError:
    return False
  with os.fdopen(fd, "w") as f:
    json.dump(content, f)
  return True


def _read(path: str) -> dict:
  try:
    with open(path) as f:
      found = json.load(f)
  except (OSError, ValueError):
    return {}
  return found if isinstance(found, dict) else {}


def _stale(path: str, found: dict) -> str | None:
  """Why the lock `found` at `path` may be taken over ("has ended", ...), or None where its
  holder may still be running. An unreadable lock counts as written when the file was."""
  beat = found.get("heartbeat")
  if not isinstance(beat, (int, float)):
    with contextlib.suppress(OSError):
      beat = os.path.getmtime(path)
  age = time.time() - (beat or 0)
  if age > STALE_S:
    return f"has not refreshed its heartbeat for {age / 60:.0f} min"
  if found.get("host") == socket.gethostname() and isinstance(found.get("pid"), int):
    if found["pid"] == os.getpid():
      return None if path in _held else "is this process, which no longer holds it"
    if not alive(found["pid"]):
      return "has ended"
  return None


def alive(pid: int) -> bool:
  """Whether process `pid` of this host runs (a zombie, dead and not yet reaped, does not;
  another user's does)."""
  if os.name == "nt":  # no signal 0 there: the heartbeat decides
    return True
  try:
    os.kill(pid, 0)
  except ProcessLookupError:
    return False
  except OSError:
    return True
  try:
    with open(f"/proc/{pid}/stat") as f:
      return f.read().rsplit(")", 1)[1].split()[0] != "Z"
  except (OSError, IndexError):  # no /proc (macOS): it runs
    return True


def _who(found: dict) -> str:
  if not found:
    return "an unreadable lock"
  return f"process {found.get('pid')} on {found.get('host')}"


def _refusal(path: str, found: dict) -> str:
  beat = found.get("heartbeat")
  seen = f", heartbeat {time.time() - beat:.0f} s ago" if isinstance(beat, (int, float)) else ""
  return (f"{os.path.dirname(path)} is in use by another run ({_who(found)}{seen}): wait for it "
          "to end, or train in another folder. If that run is gone, its lock is taken over "
          f"once its heartbeat is {STALE_S / 60:.0f} min old, or delete {path}")


def _beat(path: str, mine: dict, stop: threading.Event) -> None:
  """Refreshes the heartbeat of the lock at `path` every HEARTBEAT_S until `stop`, while the
  lock is still `mine` (a run that took it over keeps it)."""
  while not stop.wait(HEARTBEAT_S):
    if _read(path).get("token") != mine["token"]:
      return
    with contextlib.suppress(OSError):  # a full disk or a lost mount: the next beat tries again
      with open(path + ".tmp", "w") as f:
        json.dump({**mine, "heartbeat": time.time()}, f)
      os.replace(path + ".tmp", path)
