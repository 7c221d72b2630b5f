"""A ledger of the programs a process compiles: where $MJX_HOPPER_COMPILE_LEDGER names a file,
each program that XLA compiles or loads from the persistent cache, and each function traced or
lowered, appends a line to it ({"event": ..., "s": seconds}). The test suite sums the lines of
its workers and of the processes they start (tests/ledger.py); `summarise` reads them."""

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
      lambda event, secs, **_: _write(event, secs))
  monitoring.register_event_listener(lambda event, **_: _write(event, 0.0))


def _write(event: str, secs: float) -> None:
  name, path = EVENTS.get(event), os.environ.get(VARIABLE)
  if name is None or not path:
    return
  line = json.dumps({"event": name, "s": round(secs, 4)}) + "\n"
  # One write of one short line in append mode: whole lines, from several processes at once.
  fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
  try:
    os.write(fd, line.encode())
  finally:
    os.close(fd)


def summarise(paths) -> dict:
  """The totals of ledger files `paths`: programs (XLA compiles and cache loads), cache hits,
  compiled (programs not from the cache), and the seconds of compiling, tracing and lowering."""
  count, secs = collections.Counter(), collections.Counter()
  for path in paths:
    with open(path) as f:
      for line in f:
        try:
          entry = json.loads(line)
        except ValueError:
          continue  # a line cut short by a process killed as it wrote
        count[entry["event"]] += 1
        secs[entry["event"]] += entry["s"]
  return {"programs": count["compile"], "cache hits": count["cache hit"],
          "compiled": count["compile"] - count["cache hit"], "compile s": secs["compile"],
          "trace s": secs["trace"], "lower s": secs["lower"]}
