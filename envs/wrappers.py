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


# What an episode's first state sets of a State, besides its obs and pipeline_state.
_STARTED_INFO = ("robot", "feet_contact", "steps")
# Control steps of the shortest episodes that `EpisodeStarts.for_steps` makes starts for: about
# the quickest fall of a robot from its reset. An env whose episodes between two refills are
# shorter, on average, starts some of them from the state an earlier one started from.
SHORTEST_EPISODE = 16


class EpisodeStarts(Wrapper):
  """AutoReset whose new episodes start from reset states made beforehand, so that a step
  computes no reset: for one env, vmapped over a batch.

  `state.info["starts"]` holds `starts` first states and `info["starts_used"]` counts those
  taken. `reset` and `refill` make them from `env.reset` with fresh keys: call `refill` after
  each run of steps. An env that ends more than `starts` episodes between two refills
  takes its starts again, in turn. After a step that ends an episode, the state is as
  AutoReset's.
  """

  def __init__(self, env, starts: int):
    super().__init__(env)
    if not isinstance(starts, int) or starts < 1:
      raise ValueError(f"starts must be an integer >= 1, got {starts!r}")
    self.starts = starts

  @classmethod
  def for_steps(cls, env, steps: int) -> "EpisodeStarts":
    """`env` with enough starts for `steps` steps between refills in episodes of
    SHORTEST_EPISODE steps (or of the env's `episode_steps`, if shorter)."""
    shortest = min(SHORTEST_EPISODE, getattr(env, "episode_steps", SHORTEST_EPISODE))
    return cls(env, -(-steps // shortest))

  @staticmethod
  def _first(state: State) -> dict:
    """What a new episode takes of its first state."""
    return {"obs": state.obs, "pipeline_state": state.pipeline_state,
            **{k: state.info[k] for k in _STARTED_INFO}}

  def reset(self, rng: jax.Array) -> State:
    rng, key = jax.random.split(rng)
    # The episode's first state and its starts from one batch of resets: one reset in the
    # program, which compiles in half the time of two.
    firsts = jax.vmap(self.env.reset)(jax.random.split(key, self.starts + 1))
    state = jax.tree.map(lambda x: x[0], firsts)
    state.info.update(rng=rng, final_obs=state.obs,
                      starts=self._first(jax.tree.map(lambda x: x[1:], firsts)),
                      starts_used=jnp.zeros((), jnp.int32))
    return state

  def refill(self, state: State) -> State:
    """`state` with `starts` new first states, none used."""
    keys = jax.random.split(state.info["rng"], self.starts + 1)
    starts = self._first(jax.vmap(self.env.reset)(keys[1:]))
    return state.replace(info=dict(state.info, rng=keys[0], starts=starts,
                                   starts_used=jnp.zeros((), jnp.int32)))

  def step(self, state: State, action: jax.Array) -> State:
    stepped = self.env.step(state, action)
    done = stepped.done > 0
    used = state.info["starts_used"]
    start = jax.tree.map(lambda x: x[used % self.starts], state.info["starts"])

    def pick(new, old):
      return jnp.where(done, new, old)

    info = dict(stepped.info, final_obs=stepped.obs, starts_used=used + done)
    for k in _STARTED_INFO:
      info[k] = jax.tree.map(pick, start[k], stepped.info[k])
    return stepped.replace(
        pipeline_state=jax.tree.map(pick, start["pipeline_state"], stepped.pipeline_state),
        obs=pick(start["obs"], stepped.obs), info=info)
