"""One run over several processes, on JAX's distributed runtime (`jax.distributed`).

Every process runs the same programs over one global mesh of every process's devices
(`jax.devices()`), and the host loop between chunks makes the same choices everywhere: what it
reads of the state is gathered from every process (`gather`), and what only one process can know
(a signal, a clock) is agreed on (`agree`). Process 0 writes the run's files.

    loop.run(cfg, distributed=True)                                  # the launcher's variables
    loop.run(cfg, distributed=Cluster("host0:8476", num_processes=2, process_id=0))
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import threading
import time
from typing import NamedTuple

import jax
import numpy as np
from jax.experimental import multihost_utils

from mjx_hopper.process import errors, runlock, runtime

# How long the processes wait for each other to start, in seconds.
START_TIMEOUT_S = 300
# JAX's own time-out, in seconds: a process that sends its coordinator no heartbeat for this long
# counts as dead, and JAX then ends every other process (with a fatal log of its own).
HEARTBEAT_TIMEOUT_S = 100
# Our watch, before JAX's: every WATCH_S seconds each process marks itself alive in the run
# folder and reads the others' marks. A process whose mark is unchanged for STOPPED_S, whose
# pid is gone from this host, or that ended with an error, ends every other one with one line.
WATCH_S = 2.0
STOPPED_S = 60.0
WATCH_FOLDER = ".processes"


class Cluster(NamedTuple):
  """Where a process stands in a run over processes; a None is read from the launcher (SLURM,
  Open MPI, ...), as `jax.distributed.initialize` does."""

  coordinator: str | None = None    # "host:port" of process 0's coordination service
  num_processes: int | None = None
  process_id: int | None = None


class StartFailed(ValueError):
  """The processes of a run could not join each other."""


def join(cluster: Cluster | bool, start_timeout_s: int = START_TIMEOUT_S,
         heartbeat_timeout_s: int = HEARTBEAT_TIMEOUT_S) -> None:
  """Starts JAX's distributed runtime for `cluster` (True: the launcher's), and over processes on
  CPUs turns the compile cache off. Call after `mjx_hopper.setup()` (which chooses the CPU
  collectives) and before anything runs on a device; a second call changes nothing."""
  if jax.distributed.is_initialized():
    return
  cluster = Cluster() if cluster is True else Cluster(*cluster)
  _check(cluster)
  if cluster.process_id == 0 and cluster.coordinator is not None:
    _check_port_free(cluster.coordinator)
  try:
    jax.distributed.initialize(cluster.coordinator, cluster.num_processes, cluster.process_id,
                               initialization_timeout=start_timeout_s,
                               heartbeat_timeout_seconds=heartbeat_timeout_s)
  except (RuntimeError, ValueError) as error:
    raise StartFailed(_start_failure(cluster, error, start_timeout_s)) from None
  runtime.compile_cache_over_processes()


def _check(cluster: Cluster) -> None:
  count, index = cluster.num_processes, cluster.process_id
  if count is not None and (not isinstance(count, int) or count < 1):
    raise ValueError(f"the number of processes must be an integer >= 1, got {count!r}")
  if index is not None and count is not None and not 0 <= index < count:
    raise ValueError(f"process id {index} is not in 0 to {count - 1}")
  if cluster.coordinator is not None and not cluster.coordinator.rsplit(":", 1)[-1].isdigit():
    raise ValueError(f"the coordinator must be host:port, got {cluster.coordinator!r}")


def _check_port_free(coordinator: str) -> None:
  """A StartFailed where process 0 cannot serve on the coordinator's port (jaxlib's service
  crashes the process there, rather than raising)."""
  port = int(coordinator.rsplit(":", 1)[1])
  try:
    family = socket.AF_INET6 if socket.has_dualstack_ipv6() else socket.AF_INET
    with socket.create_server(("", port), family=family,
                              dualstack_ipv6=family == socket.AF_INET6):
      pass
  except OSError as error:
    raise StartFailed(f"the coordinator address {coordinator} is already in use, or not this "
                      f"host's: choose another port ({os.strerror(error.errno)})") from None


def _start_failure(cluster: Cluster, error: Exception, timeout_s: int) -> str:
  """One line saying why `jax.distributed.initialize` failed."""
  text = errors.first_line(error)
  where = cluster.coordinator or "the launcher's coordinator"
  if "already in use" in text.lower() or "address in use" in text.lower():
    return f"the coordinator address {where} is already in use: choose another port ({text})"
  if "deadline" in text.lower() or "timed out" in text.lower():
    return (f"process {cluster.process_id} could not join the run at {where} within "
            f"{timeout_s} s: are all {cluster.num_processes or 'the'} processes started, and "
            f"is the coordinator reachable? ({text})")
  if "must be defined" in text or "could not" in text.lower():
    return ("a run over processes needs --coordinator, --num-processes and --process-id, or a "
            f"launcher JAX detects (SLURM, Open MPI, ...): {text}")
  return f"the processes could not start JAX's distributed runtime: {text}"


def count() -> int:
  """The processes of the run (1 where JAX's distributed runtime is not started)."""
  return jax.process_count()


def primary() -> bool:
  """Whether this process writes the run's files (process 0)."""
  return jax.process_index() == 0


def gather(tree, phase: str):
  """`tree`'s arrays on the host, whole: gathered from every process where they span several,
  once the processes have checked that they all gather for `phase` (`in_step`)."""
  if count() == 1:
    return jax.device_get(tree)
  in_step(phase)

  def one(x):
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
      return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(jax.device_get(x))
  return jax.tree.map(one, tree)


def agree(phase: str, *flags: bool) -> tuple[bool, ...]:
  """Each of `flags`, true where it is true on any process, once the processes have checked
  that they all agree on `phase` (`in_step`)."""
  if count() == 1:
    return tuple(bool(f) for f in flags)
  return tuple(bool(f) for f in _exchange(phase, flags).any(0))


def in_step(phase: str) -> None:
  """Checks that every process has reached `phase` (a short name for a host-side step whose
  collectives follow). Where one has reached another, raises OutOfStep naming both, rather
  than letting the next collective abort inside the runtime. One small collective."""
  if count() > 1:
    _exchange(phase, ())


class OutOfStep(RuntimeError):
  """The processes of a run reached different collectives: a choice was made apart."""


# The fixed size of every exchange, so that processes out of step exchange as many bytes and
# read each other's phase, rather than aborting on a size mismatch.
PHASE_BYTES, MAX_FLAGS = 32, 8


def _exchange(phase: str, flags) -> np.ndarray:
  """(processes, len(flags)): every process's `flags`, after checking that all are at `phase`."""
  name = phase.encode()
  if len(name) > PHASE_BYTES or len(flags) > MAX_FLAGS:
    raise ValueError(f"phase {phase!r} with {len(flags)} flags: at most {PHASE_BYTES} bytes "
                     f"and {MAX_FLAGS} flags")
  mine = np.zeros(PHASE_BYTES + MAX_FLAGS, np.uint8)
  mine[:len(name)] = np.frombuffer(name, np.uint8)
  mine[PHASE_BYTES:PHASE_BYTES + len(flags)] = np.asarray(flags, bool)
  everyone = np.asarray(multihost_utils.process_allgather(mine)).reshape(count(), -1)
  phases = [bytes(row[:PHASE_BYTES]).rstrip(b"\0").decode(errors="replace") for row in everyone]
  if any(p != phase for p in phases):
    where = ", ".join(f"process {i} at {p!r}" for i, p in enumerate(phases))
    raise OutOfStep(f"the processes are out of step ({where}): a choice was made apart")
  return everyone[:, PHASE_BYTES:PHASE_BYTES + len(flags)].astype(bool)


@contextlib.contextmanager
def watch(folder: str):
  """Within `with`, ends this process with one line (on stderr; exit status 1) once another
  process of the run stops: it died, stopped answering, or left `with` by an error. An error
  leaving `with` also ends this process in one line: the distributed runtime cannot end
  cleanly without the others. Nothing where the run has one process."""
  if count() == 1:
    yield
    return
  marks = os.path.join(folder, WATCH_FOLDER)
  os.makedirs(marks, exist_ok=True)
  me = jax.process_index()
  mine = {"host": socket.gethostname(), "pid": os.getpid(), "state": "running", "beat": 0}
  stop = threading.Event()
  thread = threading.Thread(target=_watch, args=(marks, me, mine, stop), daemon=True,
                            name="mjx_hopper process watch")
  thread.start()
  try:
    yield
  except BaseException as error:
    _mark(marks, me, {**mine, "state": "failed"})
    if not isinstance(error, OutOfStep):  # which every process finds, and says, at once
      # A collective whose peer died fails at once: the watch names the peer if it finds it
      # gone.
      time.sleep(2 * WATCH_S)
    stop.set()
    text = errors.first_line(error)
    _end(f"process {me} stopped at an error: {text}")
  stop.set()
  thread.join(timeout=2 * WATCH_S)
  _mark(marks, me, {**mine, "state": "done"})


def _mark(marks: str, index: int, mark: dict) -> None:
  path = os.path.join(marks, f"{index}.json")
  with contextlib.suppress(OSError):  # a mark that cannot be written is a late one
    with open(path + ".tmp", "w") as f:
      json.dump(mark, f)
    os.replace(path + ".tmp", path)


def _read(marks: str, index: int) -> dict | None:
  try:
    with open(os.path.join(marks, f"{index}.json")) as f:
      return json.load(f)
  except (OSError, ValueError):
    return None


def _watch(marks: str, me: int, mine: dict, stop: threading.Event) -> None:
  """Marks this process alive, and judges the others by their marks; a mark counts once it has
  changed since this process started (an older run's are ignored)."""
  first = {i: _read(marks, i) for i in range(count()) if i != me}
  seen = {i: (mark, time.monotonic()) for i, mark in first.items()}
  started: set[int] = set()
  while not stop.wait(WATCH_S):
    mine["beat"] += 1
    _mark(marks, me, mine)
    for index, (last, since) in seen.items():
      mark = _read(marks, index)
      if mark != last and mark is not None:
        seen[index], last = (mark, time.monotonic()), mark
        started.add(index)
      if index not in started or stop.is_set() or last["state"] == "done":
        continue
      who = f"process {index} (pid {last['pid']} on {last['host']})"
      if last["state"] == "failed":
        _end(f"{who} ended with an error, which its own line names")
      elif last["state"] == "running" and last["host"] == mine["host"] and not runlock.alive(
          last["pid"]):
        _end(f"{who} is gone")
      elif last["state"] == "running" and time.monotonic() - seen[index][1] > STOPPED_S:
        _end(f"{who} has not answered for {STOPPED_S:.0f} s")


def _end(why: str) -> None:
  print(f"mjx-hopper: {why}: this process ends too; run the same command on every process "
        "to resume from the last checkpoint", file=sys.stderr, flush=True)
  os._exit(1)
