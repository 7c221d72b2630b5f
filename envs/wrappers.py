"""Wrappers for training."""

import jax
import jax.numpy as jnp
from brax.envs.base import State, Wrapper


class AutoReset(Wrapper):
  """Starts a new episode, with a fresh random key, as soon as one ends.

  Wraps one env (vmap it for a batch). After a step that ended an episode, `state.obs` and
  `state.pipeline_state` are the new episode's first ones, while `reward`, `done`, `metrics`
  and `info["truncation"]` describe the step just taken and `info["final_obs"]` holds the true
  last observation of the ended episode (it equals `obs` on every other step).
  """

  def reset(self, rng: jax.Array) -> State:
    rng, key = jax.random.split(rng)
    state = self.env.reset(key)
    state.info.update(rng=rng, final_obs=state.obs)
    return state

  def step(self, state: State, action: jax.Array) -> State:
    rng, key = jax.random.split(state.info["rng"])
    stepped = self.env.step(state, action)
    fresh = self.env.reset(key)
    done = stepped.done > 0

    def pick(new, old):
      return jnp.where(done, new, old)

    info = dict(stepped.info, rng=rng, final_obs=stepped.obs)
    for k in ("robot", "feet_contact", "steps"):
      info[k] = jax.tree.map(pick, fresh.info[k], stepped.info[k])
    return stepped.replace(
        pipeline_state=jax.tree.map(pick, fresh.pipeline_state, stepped.pipeline_state),
        obs=pick(fresh.obs, stepped.obs),
        info=info)
