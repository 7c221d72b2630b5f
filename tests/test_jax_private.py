"""JAX's private API that mjx_hopper/jax_private.py uses is still there, as it was read."""

import inspect

import jax
import numpy as np
import pytest

from mjx_hopper import jax_private


def test_the_cache_loader_is_where_it_was_read():
  loader = jax_private.cache_loader()
  load = loader.get_executable_and_time
  assert callable(load), f"jax {jax.__version__} moved compilation_cache.get_executable_and_time"
  if not getattr(load, "quiet", False):  # the hook passes its arguments on as they come
    assert "cache_key" in inspect.signature(load).parameters


def test_quiet_loads_keep_the_loader_working_and_are_installed_once():
  assert jax_private.backends_started() in (True, False)
  jax_private.quiet_cache_loads()
  first = jax_private.cache_loader().get_executable_and_time
  jax_private.quiet_cache_loads()
  assert jax_private.cache_loader().get_executable_and_time is first and first.quiet


def test_the_compiler_is_where_it_was_read():
  compile_ = jax_private.compiler().compile_or_get_cached
  assert callable(compile_), f"jax {jax.__version__} moved compiler.compile_or_get_cached"
  if not getattr(compile_, "serial", False):  # the hook takes the backend first, as read
    assert next(iter(inspect.signature(compile_).parameters)) == "backend"


def test_cpu_compiles_on_two_threads_take_turns_and_still_compile(monkeypatch):
  import concurrent.futures
  import threading

  jax_private.one_cpu_compile_at_a_time()
  serial = jax_private.compiler().compile_or_get_cached
  jax_private.one_cpu_compile_at_a_time()
  assert jax_private.compiler().compile_or_get_cached is serial and serial.serial
  original, lock, inside, most = serial.compile, threading.Lock(), [0], [0]

  def counting(backend, *args, **kwargs):  # how many compile at once, under the hook's lock
    with lock:
      inside[0] += 1
      most[0] = max(most[0], inside[0])
    try:
      return original(backend, *args, **kwargs)
    finally:
      with lock:
        inside[0] -= 1

  monkeypatch.setattr(serial, "compile", counting)
  programs = [jax.jit(lambda x, k=k: jax.numpy.sin(x) * k).lower(jax.numpy.ones(64 + k))
              for k in range(8)]
  with concurrent.futures.ThreadPoolExecutor(4) as pool:
    compiled = list(pool.map(lambda p: p.compile(), programs))
  assert most[0] == 1 and inside[0] == 0
  assert float(compiled[3](jax.numpy.ones(67)).sum()) == pytest.approx(67 * 3 * np.sin(1), 1e-5)
