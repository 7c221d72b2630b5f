"""JAX's private API that mjx_hopper/process/jax_private.py uses is still there, as it was read."""

import inspect

import jax

from mjx_hopper.process import jax_private


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
