"""EpisodeStarts: a training step starts new episodes from reset states made before it, drawn as
`env.reset` draws them, and computes no reset itself."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_hopper import envs

NUM_ENVS, STARTS, EPISODE = 64, 3, 4
STEPS = STARTS * EPISODE  # between refills: each env ends exactly STARTS episodes


@pytest.fixture(scope="module")
def short_hopper():
  """A Hopper whose episodes end every EPISODE steps, so that every env ends STARTS episodes
  between two refills."""
  return envs.make("Hopper", episode_steps=EPISODE)


@pytest.fixture(scope="module")
def wrapped(short_hopper):
  """`short_hopper` with STARTS starts, and its single-env reset, refill and blank programs."""
  env = envs.EpisodeStarts(short_hopper, STARTS)
  return env, jax.jit(env.reset), jax.jit(env.refill), jax.jit(env.blank)


@pytest.fixture(scope="module")
def new_episodes(short_hopper, wrapped):
  """Every env's states after the steps that began new episodes, over 4 refills: their qpos,
  qvel, obs (4, STARTS, NUM_ENVS, ...), and each env's starts as each refill left them; and
  before them, as a trainer begins its envs, blank states refilled and begun: the first
  observations of the episodes that then begin, and the starts they were taken from."""
  wrapped = wrapped[0]
  action = jnp.zeros((NUM_ENVS, short_hopper.action_size))

  # One program, as the trainer's refill: `begin` (traced) says whether a new episode begins.
  @jax.jit
  def run(state, begin):
    state = jax.vmap(wrapped.refill, (0, None))(state, begin)
    starts = state.info["starts"]

    def one(state, _):
      state = jax.vmap(wrapped.step)(state, action)
      ps = state.pipeline_state
      return state, (state.done, ps.qpos, ps.qvel, state.obs, state.info["steps"])
    state, out = jax.lax.scan(one, state, None, length=STEPS)
    return state, starts, out

  state = jax.jit(jax.vmap(wrapped.blank))(jax.random.split(jax.random.PRNGKey(7), NUM_ENVS))
  state, starts, (done, *_, obs, _) = jax.device_get(run(state, np.True_))
  # Begun from start 0, an env's episodes end at steps 3, 7 and 11 and take starts 1, 2 and 0.
  begun = {"firsts": obs[EPISODE - 1::EPISODE], "starts": starts["obs"]}
  assert done[EPISODE - 1::EPISODE].all() and done.sum() == STARTS * NUM_ENVS
  found = {"qpos": [], "qvel": [], "obs": [], "starts": []}
  for _ in range(4):
    state, starts, (done, qpos, qvel, obs, steps) = jax.device_get(run(state, np.False_))
    ended = done[EPISODE - 1::EPISODE]  # (STARTS, NUM_ENVS): the steps that end an episode
    assert ended.all() and done.sum() == ended.sum()
    assert (steps[EPISODE - 1::EPISODE] == 0).all()  # a new episode's count begins again
    for name, x in (("qpos", qpos), ("qvel", qvel), ("obs", obs)):
      found[name].append(x[EPISODE - 1::EPISODE])
    found["starts"].append(starts)
  return {k: np.stack(v) for k, v in found.items()}, begun


def test_new_episodes_start_from_the_starts_in_turn(new_episodes):
  new_episodes, _ = new_episodes
  for r, starts in enumerate(new_episodes["starts"]):
    for i in range(STARTS):  # episode i after a refill: start i
      np.testing.assert_array_equal(new_episodes["obs"][r, i], starts["obs"][:, i])
      np.testing.assert_array_equal(new_episodes["qpos"][r, i],
                                    starts["pipeline_state"].qpos[:, i])


def test_no_start_is_taken_twice(new_episodes):
  new_episodes, _ = new_episodes
  qpos = new_episodes["qpos"].reshape(-1, new_episodes["qpos"].shape[-1])
  assert len(np.unique(qpos, axis=0)) == len(qpos)


def test_starts_are_drawn_as_env_reset_draws_them(hopper_resets, new_episodes):
  """Positions, velocities and first observations of the new episodes against those of
  `env.reset` from other keys: each dimension's mean and spread agree within sampling error."""
  new_episodes, _ = new_episodes
  n = new_episodes["qpos"][..., 0].size
  drawn = hopper_resets(jax.random.split(jax.random.PRNGKey(11), n))
  reference = {"qpos": drawn.pipeline_state.qpos, "qvel": drawn.pipeline_state.qvel,
               "obs": drawn.obs}
  for name, ours in new_episodes.items():
    if name == "starts":
      continue
    ours = ours.reshape(n, -1)
    theirs = np.asarray(reference[name])
    spread = theirs.std(0)
    varies = spread > 0
    np.testing.assert_array_equal(ours[:, ~varies], theirs[:, ~varies])  # constants: exactly
    # Means within 5 standard errors, standard deviations within 10%.
    error = spread[varies] / np.sqrt(n)
    assert (np.abs(ours[:, varies].mean(0) - theirs[:, varies].mean(0)) < 5 * error).all()
    np.testing.assert_allclose(ours[:, varies].std(0), spread[varies], rtol=0.1)


def test_reset_begins_from_the_first_of_fresh_starts(wrapped, hopper_resets):
  _, reset, _, _ = wrapped
  state = reset(jax.random.PRNGKey(0))
  assert int(state.info["starts_used"]) == 1  # the first state is start 0
  # Drawn as env.reset draws, each from its own key.
  firsts = hopper_resets(jax.random.split(jax.random.PRNGKey(0), 4)[1:])
  np.testing.assert_allclose(state.info["starts"]["obs"], firsts.obs, atol=1e-6)
  np.testing.assert_allclose(state.obs, firsts.obs[0], atol=1e-6)
  np.testing.assert_allclose(state.info["final_obs"], firsts.obs[0], atol=1e-6)
  assert len({tuple(np.asarray(x).round(6)) for x in firsts.obs}) == 3  # all differ


def test_one_refill_program_refills_and_begins(wrapped):
  """A trainer's init begins its envs with the refill that follows each chunk: one program,
  whose `begin` says which."""
  _, reset, refill, blank = wrapped
  state = reset(jax.random.PRNGKey(0))
  # Two steps into its episode, as far as refill can tell: its count and pose moved on.
  ps = state.pipeline_state
  state = state.replace(pipeline_state=ps.replace(qpos=ps.qpos + 0.01),
                        info={**state.info, "steps": jnp.asarray(2, state.info["steps"].dtype)})
  kept, begun = refill(state, np.False_), refill(state, np.True_)
  np.testing.assert_array_equal(kept.pipeline_state.qpos, state.pipeline_state.qpos)
  assert int(kept.info["steps"]) == 2 and int(kept.info["starts_used"]) == 0
  np.testing.assert_array_equal(begun.obs, begun.info["starts"]["obs"][0])
  np.testing.assert_array_equal(begun.pipeline_state.qpos,
                                begun.info["starts"]["pipeline_state"].qpos[0])
  assert int(begun.info["steps"]) == 0 and int(begun.info["starts_used"]) == 1
  np.testing.assert_array_equal(kept.info["starts"]["obs"], begun.info["starts"]["obs"])
  empty = blank(jax.random.PRNGKey(5))
  assert not np.asarray(empty.obs).any() and int(empty.info["starts_used"]) == STARTS
  np.testing.assert_array_equal(refill(empty, np.True_).obs, reset(jax.random.PRNGKey(5)).obs)


def test_an_env_that_ends_more_episodes_takes_its_starts_again_in_turn(new_episodes):
  # Begun from start 0, each env's three episode ends take starts 1, 2, then 0 again.
  _, begun = new_episodes
  for end, start in enumerate((1, 2, 0)):
    np.testing.assert_array_equal(begun["firsts"][end], begun["starts"][:, start])
  assert len({f.tobytes() for f in begun["firsts"]}) == STARTS


def _calls(jaxpr) -> set[str]:
  """The names of the jitted functions that `jaxpr` calls, at any depth."""
  names = set()
  for eqn in jaxpr.eqns:
    if "name" in eqn.params:
      names.add(eqn.params["name"])
    for value in eqn.params.values():
      for x in value if isinstance(value, (tuple, list)) else (value,):
        sub = getattr(x, "jaxpr", x)  # a ClosedJaxpr's, or a Jaxpr
        if hasattr(sub, "eqns"):
          names |= _calls(sub)
  return names


def test_the_step_computes_no_reset(hopper):
  """The step's program calls MJX's kinematics only within its physics, where AutoReset's also
  calls it for the reset that every step makes."""
  keys = jax.random.split(jax.random.PRNGKey(0), 2)
  state = jax.eval_shape(jax.vmap(envs.AutoReset(hopper).reset), keys)  # traced, never run
  action = jnp.zeros((2, hopper.action_size))
  auto = jax.make_jaxpr(jax.vmap(envs.AutoReset(hopper).step))(state, action)
  assert "kinematics" in _calls(auto.jaxpr)
  wrapped = envs.EpisodeStarts(hopper, 2)
  state = jax.eval_shape(jax.vmap(wrapped.reset), keys)
  ours = jax.make_jaxpr(jax.vmap(wrapped.step))(state, action)
  assert "kinematics" not in _calls(ours.jaxpr) and "_physics" in _calls(ours.jaxpr)


@pytest.mark.parametrize("bad", [1, 2.0, "3"])
def test_bad_number_of_starts(hopper, bad):
  with pytest.raises(ValueError, match=rf"starts must be an integer >= 2 \(a first state and "
                     rf"one more\), got {bad!r}"):
    envs.EpisodeStarts(hopper, bad)
