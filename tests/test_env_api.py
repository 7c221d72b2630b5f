"""The env API: registry, errors, episodes' end flags, auto-reset, custom tasks, sharding."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import make_env
from mjx_hopper import envs
from mjx_hopper.core import rollout
from mjx_hopper.process import parallel


def test_list_and_make():
  assert envs.list_envs() == ["Ant", "HalfCheetah", "Hopper", "Humanoid", "Walker2D"]
  assert isinstance(envs.make("Hopper"), envs.Hopper)
  with pytest.raises(ValueError, match=r"unknown env 'Hoper'; valid envs are \['Ant', "):
    envs.make("Hoper")


@pytest.mark.parametrize("bad", [0, -3, 2.5, "10"])
def test_bad_episode_steps(bad):
  with pytest.raises(ValueError, match=f"episode_steps must be an integer >= 1, got {bad!r}"):
    envs.make("Hopper", episode_steps=bad)


def test_wrong_action_shape(hopper, hopper_reset):
  state = hopper_reset(jax.random.PRNGKey(0))
  with pytest.raises(ValueError, match=r"action of shape \(3,\), got \(4,\)"):
    hopper.step(state, jnp.zeros(4))
  with pytest.raises(ValueError, match=r"got \(8, 3\); for a batch of envs use jax.vmap"):
    hopper.step(state, jnp.zeros((8, 3)))


def test_termination_and_truncation_are_separate(hopper, hopper_reset, hopper_step):
  # Five steps before the time limit (the episode's step count set ahead): a truncation.
  state = hopper_reset(jax.random.PRNGKey(0))
  limit = hopper.episode_steps
  state = state.replace(info={**state.info, "steps": state.info["steps"] + limit - 5})
  for t in range(limit - 5, limit):
    state = hopper_step(state, jnp.zeros(3))
    assert int(state.info["steps"]) == t + 1
    assert float(state.done) == (1.0 if t == limit - 1 else 0.0)
  assert float(state.info["truncation"]) == 1.0  # time limit: learners bootstrap here
  assert float(state.metrics["alive"]) == 1.0

  state = hopper_reset(jax.random.PRNGKey(0))
  while float(state.done) == 0.0:
    state = hopper_step(state, jnp.zeros(3))
  assert float(state.metrics["alive"]) == -1.0  # it fell: a termination
  assert float(state.info["truncation"]) == 0.0
  assert int(state.info["steps"]) < limit


def test_non_finite_state_terminates_with_finite_outputs(hopper, hopper_reset, hopper_step):
  state = hopper_reset(jax.random.PRNGKey(0))
  data = state.pipeline_state
  state = state.replace(pipeline_state=data.replace(qvel=data.qvel.at[0].set(jnp.nan)))
  state = hopper_step(state, jnp.zeros(3))
  assert float(state.done) == 1.0 and float(state.info["truncation"]) == 0.0
  assert np.isfinite(state.obs).all() and np.isfinite(float(state.reward))


def bare(env, state):
  """A wrapper's `state` as `env`'s own, its wrapper's info left out, so that `env`'s own step
  program takes it (a state of another structure would be another program). `env`'s info is
  read with `jax.eval_shape`, which compiles nothing."""
  own = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).info
  return state.replace(info={k: v for k, v in state.info.items() if k in own})


def test_auto_reset_keeps_final_observation(hopper, hopper_step):
  env = envs.AutoReset(hopper)
  reset, step = jax.jit(env.reset), jax.jit(env.step)
  state = reset(jax.random.PRNGKey(3))
  for _ in range(200):
    expected = hopper_step(bare(hopper, state), jnp.zeros(3))
    state = step(state, jnp.zeros(3))
    # Two compiled programs (the wrapped step and the bare one) may fuse and vectorise the same
    # float32 physics differently, more so on another CPU (AVX-512 or not): 4 substeps with a
    # contact solve put their last bits ~1e-5 apart (8e-6 seen). The observations are O(1), so
    # 1e-4 is far below any real difference, such as the next episode's first observation.
    np.testing.assert_allclose(state.info["final_obs"], expected.obs, rtol=1e-5, atol=1e-4)
    assert float(state.reward) == pytest.approx(float(expected.reward), rel=1e-5, abs=1e-4)
    if float(state.done):
      break
  else:
    pytest.fail("no episode ended in 200 zero-action steps")
  assert int(state.info["steps"]) == 0  # a new episode has begun
  assert not np.array_equal(state.obs, state.info["final_obs"])
  np.testing.assert_array_equal(state.obs[-1], 0.0)  # feet contact zeroed, as at reset
  assert np.abs(np.asarray(state.pipeline_state.qpos[3:])).max() <= 0.1
  state = step(state, jnp.zeros(3))  # and it goes on
  assert int(state.info["steps"]) == 1


def seed_style_task(base):
  """The seed notebook's custom env, on any robot: a fixed episode length, and its own reward
  and termination."""

  class Custom(base):
    def reward(self, before, after, action):
      terms = super().reward(before, after, action)
      terms["progress"] = 2.0 * terms["progress"]
      terms["height"] = after.body_xyz[2] - 1.0
      return terms

    def is_done(self, robot, terms):
      return super().is_done(robot, terms) | (jnp.abs(robot.body_rpy[1]) > 0.3)

  return Custom(episode_steps=40)


def test_edit_model_changes_the_physics(hopper, hopper_reset, hopper_step):
  class MoonHopper(type(hopper)):
    def edit_model(self, model):
      model.opt.gravity[2] = -1.62

  moon = MoonHopper()
  assert hopper.mj_model.opt.gravity[2] == pytest.approx(-9.8)  # the shipped one is untouched
  # At rest 1 m up, the robot falls for a step: a reset state so placed (the step computes the
  # rest from qpos and qvel), stepped by each env's own program.
  reset = hopper_reset(jax.random.PRNGKey(0))
  ps = reset.pipeline_state
  qpos = np.array(hopper.mj_model.qpos0)
  qpos[1] += 1.0  # the root's z slide
  falling = reset.replace(pipeline_state=ps.replace(qpos=jnp.asarray(qpos, ps.qpos.dtype),
                                                    qvel=jnp.zeros_like(ps.qvel)))
  for env, g in ((hopper, 9.8), (moon, 1.62)):
    state = (hopper_step if env is hopper else jax.jit(env.step))(falling, jnp.zeros(3))
    np.testing.assert_allclose(state.pipeline_state.qvel[:3], [0, -g * env.control_dt, 0],
                               rtol=1e-3, atol=1e-4)


# Subclassing works the same way for every robot: the Hopper keeps the shared termination rule
# and HalfCheetah has its own, which the subclass's rule adds to. test_episodes holds every
# robot's own reward and termination to PyBullet's.
# Slow: a second robot's programs of its own (its termination rule; the Hopper's is shared).
@pytest.mark.parametrize("robot", ["Hopper", pytest.param("HalfCheetah", marks=pytest.mark.slow)])
def test_custom_task_by_subclassing_jits_and_vmaps(robot):
  base_env = make_env(robot)
  env = seed_style_task(type(base_env))
  assert env.episode_steps == 40
  actions = 0.3 * jnp.sin(jnp.arange(8 * env.action_size)).reshape(8, env.action_size)

  @jax.jit
  def forty_steps(keys):
    def one(state, _):
      nxt = jax.vmap(env.step)(state, actions)
      return nxt, (state.info["robot"], nxt.info["robot"], nxt.metrics, nxt.reward, nxt.done,
                   nxt.info["truncation"])
    return jax.lax.scan(one, jax.vmap(env.reset)(keys), None, length=40)[1]

  before, after, terms, reward, done, truncation = jax.device_get(
      forty_steps(jax.random.split(jax.random.PRNGKey(0), 8)))
  assert set(terms) == set(envs.REWARD_TERMS) | {"height"}
  # The new terms are what the subclass says, and the others are the robot's own.
  base_terms = jax.jit(jax.vmap(jax.vmap(base_env.reward), (0, 0, None)))(before, after,
                                                                          actions)
  np.testing.assert_allclose(terms["progress"], 2 * base_terms["progress"], rtol=1e-5, atol=1e-5)
  np.testing.assert_allclose(terms["height"], after.body_xyz[..., 2] - 1.0, atol=1e-6)
  for name in set(envs.REWARD_TERMS) - {"progress"}:
    np.testing.assert_allclose(terms[name], base_terms[name], atol=1e-6)
  np.testing.assert_allclose(reward, sum(terms.values()), rtol=1e-5, atol=1e-5)
  # Every episode ends, by the 40-step limit at the latest, and only for a reason.
  ended = np.argmax(done > 0, axis=0)
  assert (done > 0).any(0).all()
  pitch = np.abs(after.body_rpy[..., 1])
  own_rule = np.asarray(jax.jit(jax.vmap(jax.vmap(base_env.is_done)))(after, base_terms))
  why = (pitch > 0.3) | own_rule | (truncation > 0)
  assert why[ended, np.arange(8)].all()
  for env_index, t in enumerate(ended):
    assert not why[:t, env_index].any()
    assert (truncation[t, env_index] > 0) == (t == 39 and pitch[t, env_index] <= 0.3
                                               and not own_rule[t, env_index])


def test_batch_is_sharded_across_devices(hopper, hopper_step):
  assert len(jax.devices()) == 2  # conftest splits the CPU in two
  # The stepper's batch, as reset (its `run` steps the same shares with shard_map; the demo
  # and notebook tests run it).
  init, _ = rollout.make_stepper(hopper, num_envs=8, steps=5)
  state = init(jax.random.PRNGKey(0))
  assert len(state.obs.sharding.device_set) == 2
  assert state.obs.addressable_shards[0].data.shape == (4, hopper.observation_size)
  # A sharded step gives each env's own step, up to float reassociation (XLA vectorises a
  # batch and a single env differently).
  actions = jnp.linspace(-1, 1, 24).reshape(8, 3)
  state = bare(hopper, state)
  sharded = jax.jit(jax.vmap(hopper.step))(state, actions)
  assert len(sharded.obs.sharding.device_set) == 2
  host = jax.device_get(state)
  for i in range(8):
    alone = hopper_step(jax.tree.map(lambda x: x[i], host), actions[i])
    np.testing.assert_allclose(sharded.obs[i], alone.obs, atol=5e-4)


def test_parallel_shard_leaves_uneven_batches_alone():
  x = jnp.zeros((3, 2))
  assert parallel.shard(x) is x
  assert parallel.batch_sharding(4) is not None
