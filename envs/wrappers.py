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
  taken. `refill` makes them from `env.reset` with fresh keys: call it after each run of
  steps. An env that ends more than its unused starts' episodes between two refills takes its
  starts again, in turn. A first state is the first of the starts of a refill that `begin`s:
  `reset` refills a `blank` state so, and a trainer can, so that only its refill holds a reset.
  After a step that ends an episode, the state is as AutoReset's.
  """

  def __init__(self, env, starts: int):
    super().__init__(env)
    if not isinstance(starts, int) or starts < 2:
      raise ValueError(f"starts must be an integer >= 2 (a first state and one more), got "
                       f"{starts!r}")
    self.starts = starts

  @classmethod
  def for_steps(cls, env, steps: int) -> "EpisodeStarts":
    """`env` with enough starts for `steps` steps between refills in episodes of
    SHORTEST_EPISODE steps (or of the env's `episode_steps`, if shorter), and one for the first
    state."""
    shortest = min(SHORTEST_EPISODE, getattr(env, "episode_steps", SHORTEST_EPISODE))
    return cls(env, -(-steps // shortest) + 1)

  @staticmethod
  def _first(state: State) -> dict:
    """What a new episode takes of its first state."""
    return {"obs": state.obs, "pipeline_state": state.pipeline_state,
            **{k: state.info[k] for k in _STARTED_INFO}}

  def blank(self, rng: jax.Array) -> State:
    """A state of zeros with the key `rng`, whose starts are all used: `refill` with `begin`
    makes it a first state."""
    # Shapes of a begun state, traced, not computed; from one reset's, as vmap traces slower.
    one = jax.eval_shape(self.env.reset, rng)
    firsts = jax.tree.map(lambda s: jax.ShapeDtypeStruct((self.starts, *s.shape), s.dtype), one)
    shapes = jax.eval_shape(self._begun, firsts, rng)
    state = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
    state.info.update(rng=rng, starts_used=jnp.asarray(self.starts, jnp.int32))
    return state

  def _begun(self, firsts: State, rng: jax.Array) -> State:
    """The first of `firsts` (a batch of `starts` resets), begun, with all of them as starts."""
    state = jax.tree.map(lambda x: x[0], firsts)
    state.info.update(rng=rng, final_obs=state.obs, starts=self._first(firsts),
                      starts_used=jnp.ones((), jnp.int32))
    return state

  def reset(self, rng: jax.Array) -> State:
    return self.refill(self.blank(rng), begin=True)

  def refill(self, state: State, begin=False) -> State:
    """`state` with `starts` new first states, none used. With `begin` (a bool, or a traced
    one), a new episode from the first of them, which it counts as used, as `reset` makes."""
    keys = jax.random.split(state.info["rng"], self.starts + 1)
    firsts = jax.vmap(self.env.reset)(keys[1:])
    refilled = state.replace(info=dict(state.info, rng=keys[0], starts=self._first(firsts),
                                       starts_used=jnp.zeros((), jnp.int32)))
    if begin is False:
      return refilled
    return jax.tree.map(lambda new, old: jnp.where(begin, new, old),
                        self._begun(firsts, keys[0]), refilled)

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
