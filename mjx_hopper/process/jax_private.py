"""The one place that uses JAX's private API, for what no public API offers. Each use names the
JAX versions it was checked against, and tests/test_jax_private.py fails when JAX changes it."""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading

# What XLA logs when it loads a cached program, that no user can act on: jaxlib's CPU loader
# reports the tuning preferences it adds itself on AVX-512 hosts (+prefer-no-gather/scatter,
# which no host lists) as missing features, and PjRt says it does not version executables. Any
# other line, a real missing feature included, is shown.
HARMLESS_LOAD_LINES = ("Target machine feature +prefer-no-",
                       "Assume version compatibility. PjRt-IFRT does not track")
CHECKED = ("0.9.2", "0.11.2", "0.12.0.1")  # the JAX versions each use here was read and tested in
_STDERR_LOCK = threading.Lock()


def backends_started() -> bool:
  """Whether JAX has started its backends, after which XLA reads no more flags."""
  if "jax" not in sys.modules:
    return False
  from jax._src import xla_bridge
  return xla_bridge.backends_are_initialized()


def cache_loader():
  """`jax._src.compilation_cache`, whose `get_executable_and_time` loads a cached program."""
  from jax._src import compilation_cache
  return compilation_cache


def quiet_cache_loads() -> None:
  """Keeps HARMLESS_LOAD_LINES out of what JAX's persistent-cache loads print (once)."""
  module = cache_loader()
  load = module.get_executable_and_time
  if getattr(load, "quiet", False):
    return

  def quiet_load(*args, **kwargs):
    with _stderr_without(HARMLESS_LOAD_LINES):
      return load(*args, **kwargs)

  quiet_load.quiet = True
  module.get_executable_and_time = quiet_load


@contextlib.contextmanager
def _stderr_without(patterns: tuple[str, ...]):
  """Runs the block with file descriptor 2 (where C++ logs go) captured, then writes back what
  it got, less the lines that contain one of `patterns`. One block at a time."""
  with _STDERR_LOCK, tempfile.TemporaryFile() as capture:
    sys.stderr.flush()
    saved = os.dup(2)
    os.dup2(capture.fileno(), 2)
    try:
      yield
    finally:
      sys.stderr.flush()
      os.dup2(saved, 2)
      os.close(saved)
      capture.seek(0)
      lines = capture.read().splitlines(keepends=True)
      os.write(2, b"".join(line for line in lines
                           if not any(p.encode() in line for p in patterns)))
