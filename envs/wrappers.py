"""Wrappers for training."""

import jax
import jax.numpy as jnp
from brax.envs.base import State, Wrapper


def _split(rng: jax.Array) -> tuple[jax.Array, jax.Array]:
  """(next rng, reset key) of raw (..., 2) or typed (...) keys, over any batch axes."""
  typed = jnp.issubdtype(rng.dtype, jax.dtypes.prng_key)
  pair = jnp.vectorize(jax.random.split, signature="()->(2)" if typed else "(2)->(2,2)")(rng)
  return (pair[..., 0], pair[..., 1]) if typed else (pair[..., 0, :], pair[..., 1, :])


class AutoReset(Wrapper):
  """Starts a new episode, with a fresh key, as soon as one ends.

  Wraps one env or a batch (Brax's VmapWrapper). After a step that ends an episode, `obs` and
  `pipeline_state` are the next episode's first, while `reward`, `done`, `metrics` and
  `info["truncation"]` describe the step taken and `info["final_obs"]` is its true last
  observation.
  """

  def reset(self, rng: jax.Array) -> State:
    rng, key = _split(rng)
    state = self.env.reset(key)
    state.info.update(rng=rng, final_obs=state.obs)
    return state

  def step(self, state: State, action: jax.Array) -> State:
    rng, key = _split(state.info["rng"])
    stepped = self.env.step(state, action)
    fresh = self.env.reset(key)
    done = stepped.done > 0

    def pick(new, old):
      return jnp.where(jnp.reshape(done, done.shape + (1,) * (new.ndim - done.ndim)), new, old)

    info = dict(stepped.info, rng=rng, final_obs=stepped.obs)
    for k in ("robot", "feet_contact", "steps"):
      info[k] = jax.tree.map(pick, fresh.info[k], stepped.info[k])
    return stepped.replace(
        pipeline_state=jax.tree.map(pick, fresh.pipeline_state, stepped.pipeline_state),
        obs=pick(fresh.obs, stepped.obs),
        info=info)
