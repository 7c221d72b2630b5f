"""A ledger of the programs a process compiles: where $MJX_HOPPER_COMPILE_LEDGER names a file,
each program that XLA compiles or loads from the persistent cache, and each function traced or
lowered, appends a line to it ({"event": ..., "s": seconds, "function": its name}). The test
suite sums the lines of its workers and of the processes they start (tests/ledger.py);
`summarise` reads them."""

from __future__ import annotations

import collections
import json
import os

VARIABLE = "MJX_HOPPER_COMPILE_LEDGER"
# JAX's monitoring events, by the ledger's names. A program from the persistent cache is a
# "compile" (XLA's step, short: the load) and a "cache hit".
EVENTS = {"/jax/core/compile/backend_compile_duration": "compile",
          "/jax/core/compile/jaxpr_trace_duration": "trace",
          "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/compilation_cache/cache_hits": "cache hit"}
_started = False


def start() -> None:
  """Listens to JAX's events for the rest of the process, appending to the file that
  $MJX_HOPPER_COMPILE_LEDGER names at each event (none while it is unset). Once per process."""
  global _started
  if _started:
    return
  _started = True
  from jax import monitoring
  monitoring.register_event_duration_secs_listener(
      lambda event, secs, fun_name="", **_: _write(event, secs, fun_name))
  monitoring.register_event_listener(lambda event, **_: _write(event, 0.0, ""))


def note(event: str, name: str) -> None:
  """Appends an event of the caller's own to the ledger, where one is kept: `name` once built
  (`run.trainers.assemble` notes each trainer configuration it builds, as "trainer")."""
  if os.environ.get(VARIABLE):
    _append(event, 0.0, name)


def _write(event: str, secs: float, function: str) -> None:
  if event in EVENTS and os.environ.get(VARIABLE):
    _append(EVENTS[event], secs, function)


def _append(name: str, secs: float, function: str) -> None:
  path = os.environ[VARIABLE]
  line = json.dumps({"event": name, "s": round(secs, 4), "function": function}) + "\n"
  # One write of one short line in append mode: whole lines, from several processes at once.
  fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
  try:
    os.write(fd, line.encode())
  finally:
    os.close(fd)


def summarise(paths) -> dict:
  """The totals of ledger files `paths`: programs (XLA compiles and cache loads), cache hits,
  compiled (programs not from the cache), the seconds of compiling, tracing and lowering, and
  the names noted as "trainer"."""
  count, secs, trainers = collections.Counter(), collections.Counter(), set()
  for path in paths:
    with open(path) as f:
      for line in f:
        try:
          entry = json.loads(line)
        except ValueError:
          continue  # a line cut short by a process killed as it wrote
        count[entry["event"]] += 1
        secs[entry["event"]] += entry["s"]
        if entry["event"] == "trainer":
          trainers.add(entry["function"])
  return {"programs": count["compile"], "cache hits": count["cache hit"],
          "compiled": count["compile"] - count["cache hit"], "compile s": secs["compile"],
          "trace s": secs["trace"], "lower s": secs["lower"], "trainers": trainers}
