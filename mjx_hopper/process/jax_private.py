"""The one place that uses JAX's private API, for what no public API offers. Each use names the
JAX versions it was checked against, and tests/test_jax_private.py fails when JAX changes it."""

from __future__ import annotations

import sys

CHECKED = ("0.9.2", "0.11.2", "0.12.0.1")  # the JAX versions each use here was read and tested in


def backends_started() -> bool:
  """Whether JAX has started its backends, after which XLA reads no more flags."""
  if "jax" not in sys.modules:
    return False
  from jax._src import xla_bridge
  return xla_bridge.backends_are_initialized()
