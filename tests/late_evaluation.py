"""`mjx-hopper ARGS...` as one process of a run over processes, a chunk taking at least a second,
whose evaluation compiles later than the others' (`LATE_EVALUATION_S` seconds on process 1), as
on a loaded machine: the run's choices must not rest on when one process's program is ready
(tests/test_sweep.py)."""

import os
import sys
import time

import jax

from mjx_hopper.core import evaluator
from mjx_hopper.faces import cli
from mjx_hopper.run import loop

lower, chunk = evaluator.lower, loop.Chunk.__call__


def late_lower(*args):
  if jax.process_index() == 1:
    time.sleep(float(os.environ["LATE_EVALUATION_S"]))
  return lower(*args)


def slow_chunk(self, state):
  time.sleep(1)
  return chunk(self, state)


if __name__ == "__main__":
  evaluator.lower, loop.Chunk.__call__ = late_lower, slow_chunk
  cli.main(sys.argv[1:])
