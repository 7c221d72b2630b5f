"""A process for the checkpoint fault tests: saves step 1 in full, then starts saving a large
step 2 and waits to be killed while it writes.

    python checkpoint_worker.py DIR
"""

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from mjx_hopper import store
from mjx_hopper.core import train

CONFIG = {"env": "Hopper", "agent": "d4pg", "seed": 0}


def state(step: int, rows: int = 256) -> train.TrainState:
  """A TrainState-shaped pytree whose every leaf depends on `step`."""
  return train.TrainState(
      agent={"w": jnp.full((64, 64), step, jnp.float32)},
      replay=jnp.arange(rows * 64, dtype=jnp.float32).reshape(rows, 64) + step,
      env={"qpos": jnp.full((4, 7), step, jnp.float32)},
      episode_return=jnp.full(4, step, jnp.float32), key=jax.random.PRNGKey(step),
      iteration=jnp.asarray(step, jnp.int32), updates=jnp.asarray(10 * step, jnp.int32),
      replay_ratio=jnp.asarray(step, jnp.float32))


if __name__ == "__main__":
  mngr = store.manager(sys.argv[1])
  store.save(mngr, state(1), CONFIG)
  store.wait_and_record(mngr)
  # About 1 GB of random floats (zstd cannot shrink them): seconds of writing. Drawn by NumPy:
  # the suite's XLA flags compile for speed of compiling, and JAX's draw then takes half a minute.
  noise = np.random.default_rng(0).standard_normal((4_000_000, 64), np.float32)
  big = state(2, rows=4_000_000)._replace(replay=jnp.asarray(noise))
  store.save(mngr, big, CONFIG)
  print("saving step 2", flush=True)
  time.sleep(600)
