"""A run's start: the programs it runs before its first evaluation, compiled side by side in
threads (XLA's compile releases Python's lock), in the order the run needs them."""

from __future__ import annotations

import concurrent.futures
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mjx_hopper import train


class Started(NamedTuple):
  """Futures of what a run waits for before it trains."""
  state: concurrent.futures.Future    # the members' fresh TrainState
  chunk: concurrent.futures.Future    # the compiled training chunk
  finite: concurrent.futures.Future   # compiled `finite_members` of the members' agents


def start(trainer: train.Trainer, init, evaluator) -> Started:
  """Starts making the fresh state (`init()`) and compiling the chunk, the evaluation (which
  `evaluator` keeps) and the finiteness check, at most `workers()` at once: the chunk and the
  state first, as the first training row waits for both. Each program is traced here, in turn,
  since tracing holds Python's lock; the state's program is traced in its thread."""
  shapes = jax.tree.map(
      lambda sharding, part: jax.tree.map(
          lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding), part),
      trainer.shardings, jax.eval_shape(init))
  pool = concurrent.futures.ThreadPoolExecutor(workers())
  chunk = pool.submit(trainer.train_chunk.lower(shapes).compile)
  state = pool.submit(init)
  evaluator.compile_in(pool, shapes.agent)
  finite = pool.submit(finite_members.lower(shapes.agent).compile)
  pool.shutdown(wait=False)
  return Started(state, chunk, finite)


def workers() -> int:
  """Programs compiled at once: on a small CPU, more would slow the chunk, which the first
  training row waits for, for programs it does not need."""
  return max(2, min(4, (os.cpu_count() or 2) // 2))


@jax.jit
def finite_members(tree) -> jax.Array:
  """(members,): whether every float of each member's part of `tree` is finite."""
  checks = [jnp.isfinite(x).reshape(x.shape[0], -1).all(1) for x in jax.tree.leaves(tree)
            if jnp.issubdtype(x.dtype, jnp.floating) and x.size]
  return jnp.stack(checks).all(0)
