"""A run's start: the programs it runs before its first evaluation, compiled in two threads
(XLA's compile releases Python's lock), in the order the run needs them."""

from __future__ import annotations

import concurrent.futures
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjx_hopper.core import train
from mjx_hopper.process import parallel


# The fewest cores on which the evaluation is traced while the chunk compiles: one for the
# chunk's compile, one for the fresh state's, one for the tracing, and one to spare.
TRACE_BESIDE_FROM_CORES = 4
BEGIN = jax.ShapeDtypeStruct((), bool)  # the refill's `begin`


class Started(NamedTuple):
  """Futures of what a run waits for before it trains."""
  state: concurrent.futures.Future    # the members' fresh TrainState
  chunk: concurrent.futures.Future    # the compiled training chunk
  refill: concurrent.futures.Future   # the compiled refill of the episode starts (`init`'s)
  finite: concurrent.futures.Future   # compiled `finite_members` of the members' agents
  evaluation: concurrent.futures.Future  # the compiled evaluation (`evaluator.lower`)


def start(trainer: train.Trainer, init, lower_evaluation) -> Started:
  """Starts making the fresh state (the blank `init(begin=False)`, whose envs begin in the
  trainer's refill, as `init()` does) and compiling the chunk, the finiteness check and the
  evaluation (`lower_evaluation(agent_shapes)`, lowered). The first training row needs the
  chunk, the state and the check, which come first, side by side: the chunk in one thread, the
  state and the check in the other. The evaluation follows, on a small CPU after the chunk in
  its thread, so as not to slow its compile. The programs are traced here, in turn, since
  tracing holds Python's lock; the state's programs (the refill's too) are traced in its
  thread, and on a small CPU the evaluation in the chunk's."""
  shapes = jax.tree.map(
      lambda sharding, part: jax.tree.map(
          lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding), part),
      trainer.shardings, jax.eval_shape(functools.partial(init, begin=False)))
  # Two lines: the chunk, then the evaluation (compiled beside the chunk, it slowed the chunk's
  # compile more than it brought the first evaluation forward); the state (its program and the
  # refill), then the finiteness check. Tracing here, during the chunk's compile, brings the
  # evaluation forward where cores are to spare; on a small CPU it slowed the compiles that the
  # first row waits for.
  lines = [concurrent.futures.ThreadPoolExecutor(1), concurrent.futures.ThreadPoolExecutor(1)]
  chunk = lines[0].submit(trainer.chunk.lower(shapes).compile)
  # The refill compiled from the shapes, then run on the blank state: traced once (`init()`
  # would trace it again, for its arguments' shardings).
  refill = lines[1].submit(trainer.refill.lower(shapes.env, BEGIN).compile)
  state = lines[1].submit(lambda: _begun(init(begin=False), refill.result()))
  finite = lines[1].submit(finite_members.lower(shapes.agent).compile)
  lowered = lower_evaluation(shapes.agent) if parallel.cores() >= TRACE_BESIDE_FROM_CORES else None

  def evaluation_after_the_first_row():
    # The evaluation's compile waits for the programs of the first training row, which it
    # would slow where cores are few.
    finite.result()
    return (lowered or lower_evaluation(shapes.agent)).compile()
  evaluation = lines[0].submit(evaluation_after_the_first_row)
  for line in lines:
    line.shutdown(wait=False)
  return Started(state, chunk, refill, finite, evaluation)


def _begun(blank: train.TrainState, refill) -> train.TrainState:
  """`blank` with its envs begun by the compiled `refill`."""
  return blank._replace(env=refill(blank.env, np.True_))


@jax.jit
def finite_members(tree) -> jax.Array:
  """(members,): whether every float of each member's part of `tree` is finite."""
  checks = [jnp.isfinite(x).reshape(x.shape[0], -1).all(1) for x in jax.tree.leaves(tree)
            if jnp.issubdtype(x.dtype, jnp.floating) and x.size]
  return jnp.stack(checks).all(0)

