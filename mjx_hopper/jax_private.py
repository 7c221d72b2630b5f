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
_CPU_COMPILE_LOCK = threading.RLock()


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


def compiler():
  """`jax._src.compiler`, whose `compile_or_get_cached(backend, ...)` compiles a program, or
  loads it from the persistent cache, and writes what it compiled there."""
  from jax._src import compiler as module
  return module


def one_cpu_compile_at_a_time() -> None:
  """Makes this process compile its CPU programs one at a time (once); other backends' compiles
  are left as they come. On jax 0.12 a worker of CI's suite crashed (a segfault in
  `executable.serialize()`, as the cache wrote the chunk) while the start's other thread
  compiled; a run's start compiles on two threads to overlap its tracing with XLA's work."""
  module = compiler()
  compile_ = module.compile_or_get_cached
  if getattr(compile_, "serial", False):
    return

  def serial(backend, *args, **kwargs):
    if backend.platform != "cpu":
      return serial.compile(backend, *args, **kwargs)
    with _CPU_COMPILE_LOCK:
      return serial.compile(backend, *args, **kwargs)

  serial.serial, serial.compile = True, compile_
  module.compile_or_get_cached = serial


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
