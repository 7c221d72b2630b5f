"""Observations, body positions and speeds against PyBullet's `calc_state`, state for state, as
tests/record_oracle.py recorded them in tests/oracle/."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import ROBOTS, make_env, oracle
from mjx_hopper import envs
from mjx_hopper.envs import base


@pytest.fixture(scope="module")
def start_and_step():
  """A robot's one program for these tests (by its name, or a name and an env of its own):
  the state that `init_state` makes from (qpos, qvel), and that state after one control step
  of `action`."""
  jitted = {}

  def get(name, env=None):
    if name not in jitted:
      env = env or make_env(name)

      def both(qpos, qvel, action):
        start = env.init_state(qpos, qvel)
        return start, env.step(start, action)
      jitted[name] = jax.jit(both)
    return jitted[name]
  return get


def named(name, physics):
  """`start_and_step`'s name for robot `name` stepped by `physics` (MJX's: the robot's own)."""
  return name if physics == "mjx" else f"{name} {physics}"


def init_state(program, env, qpos, qvel):
  """`env.init_state(qpos, qvel)` through `start_and_step`'s `program`."""
  return program(qpos, qvel, np.zeros(env.action_size, np.float32))[0]


@pytest.mark.parametrize("robot", ROBOTS)
def test_reset_observation_matches_bullet(robot, start_and_step):
  """Bullet's reset with seeds 0, 1 and 2 (tests/record_oracle.py): its observation from its
  joints' positions, and ours from the same."""
  env, bullet = make_env(robot), oracle(robot)
  assert len(bullet["reset_obs"]) == 3
  for positions, bullet_obs in zip(bullet["reset_joint_positions"], bullet["reset_obs"]):
    qpos = np.array(env.mj_model.qpos0)
    qpos[env._qadr] = positions
    state = init_state(start_and_step(robot), env, qpos, np.zeros(env.mj_model.nv))
    np.testing.assert_allclose(state.obs, bullet_obs, atol=2e-5)
    assert state.obs.dtype == jnp.float32


@pytest.mark.parametrize("physics", base.PHYSICS)
@pytest.mark.parametrize("robot", ROBOTS)
def test_observation_matches_bullet_at_random_states(robot, physics, start_and_step):
  """At 10 random states (every joint within its limits, a perturbed root, random speeds) put
  into Bullet's robot by hand; the poses from either physics engine's kinematics."""
  env, bullet = make_env(robot, physics), oracle(robot)
  assert len(bullet["random_qpos"]) == 10
  for i, (qpos, qvel) in enumerate(zip(bullet["random_qpos"], bullet["random_qvel"])):
    state = init_state(start_and_step(named(robot, physics), env), env, qpos, qvel)
    np.testing.assert_allclose(state.obs, bullet["random_obs"][i], atol=5e-5)
    robot_state = state.info["robot"]
    np.testing.assert_allclose(robot_state.body_xyz, bullet["random_body_xyz"][i], atol=1e-5)
    np.testing.assert_allclose(env.torso_speed(state), bullet["random_torso_speed"][i],
                               atol=1e-5)
    positions = env.body_positions(state)
    assert sorted(positions) == sorted(bullet["parts"])
    for name, xyz in zip(bullet["parts"], bullet["random_part_xyz"][i]):
      np.testing.assert_allclose(positions[name], xyz, atol=1e-5)


class BulletHumanoid(envs.Humanoid):
  """The Humanoid without the hinge armature that we add for stability (fidelity.md)."""

  def edit_model(self, model):
    model.dof_armature[:] = 0.0


def one_step(program, bullet, seed):
  """From the random airborne states that Bullet stepped once with rng seed `seed`
  (tests/record_oracle.py), one control step of ours (`start_and_step`'s `program`): our
  observations before and after it, Bullet's after it, our progress and Bullet's."""
  names = ("qpos", "qvel", "action", "obs", "progress")
  for qpos, qvel, action, bullet_obs, bullet_progress in zip(
      *(bullet[f"step{seed}_{k}"] for k in names)):
    start, state = program(qpos, qvel, np.asarray(action, np.float32))
    yield start.obs, state.obs, bullet_obs, float(state.metrics["progress"]), bullet_progress


@pytest.mark.parametrize("physics", base.PHYSICS)
@pytest.mark.parametrize("robot", ROBOTS)
def test_one_step_matches_bullet(robot, physics, start_and_step):
  """After a control step PyBullet reports poses one substep old: so must we, in either physics
  engine. In the air, with no contact, only the integrators differ."""
  env = BulletHumanoid(physics=physics) if robot == "Humanoid" else make_env(robot, physics)
  program = start_and_step(named(type(env).__name__, physics), env)
  speed = np.zeros(env.observation_size, bool)
  speed[3:6] = True  # Bullet takes the link speed from a part-updated pose: see fidelity.md
  if robot == "Humanoid":  # Bullet's arms collide with its body, ours do not: leave them out
    arms = [i for i, j in enumerate(env.joints) if "shoulder" in j or "elbow" in j]
    speed[[8 + 2 * i + k for i in arms for k in (0, 1)]] = True
  # Free-floating robots agree less well (fidelity.md): their base is Bullet's root link.
  tolerance = 0.01 if env._root == "planar" else 0.05
  for _, obs, bullet_obs, progress, bullet_progress in one_step(program, oracle(robot), 2):
    assert progress == pytest.approx(bullet_progress, rel=0.02, abs=0.02)
    np.testing.assert_allclose(obs[~speed], bullet_obs[~speed], atol=tolerance)
    np.testing.assert_allclose(obs[3:6], bullet_obs[3:6], atol=0.05)


def test_humanoid_armature_only_slows_the_joints(start_and_step):
  """The shipped Humanoid's hinge armature leaves the pose after a step as Bullet's, and its
  joints' speeds change less in the step than without armature."""
  env, bullet = make_env("Humanoid"), oracle("Humanoid")
  positions = 8 + 2 * np.arange(len(env.joints))
  speeds = positions + 1
  assert len(bullet["step3_obs"]) == 4
  shipped = one_step(start_and_step("Humanoid"), bullet, 3)
  without = list(one_step(start_and_step("BulletHumanoid", BulletHumanoid()), bullet, 3))
  for (start, obs, bullet_obs, _, _), (_, free, _, _, _) in zip(shipped, without):
    np.testing.assert_allclose(obs[positions], bullet_obs[positions], atol=0.05)
    np.testing.assert_allclose(obs[speeds], bullet_obs[speeds], atol=0.15)
    change, free_change = (np.linalg.norm(o[speeds] - start[speeds]) for o in (obs, free))
    assert change < 0.8 * free_change


def test_feet_contact_lags_one_step(hopper, hopper_reset, hopper_step):
  state = hopper_reset(jax.random.PRNGKey(0))
  assert state.obs[-1] == 0.0  # zeroed at reset, like PyBullet
  seen = []
  for _ in range(30):
    before = state.info["feet_contact"]
    state = hopper_step(state, jnp.zeros(3))
    np.testing.assert_array_equal(state.obs[-1:], before)  # last step's contact
    seen.append(float(state.info["feet_contact"][0]))
  assert 0.0 in seen and 1.0 in seen  # it falls onto its foot within 30 steps


def test_quat_to_rpy_matches_bullet():
  """Against pybullet.getEulerFromQuaternion on 200 random unit quaternions (w, x, y, z)."""
  bullet = oracle("euler")
  assert bullet["quats"].shape == (200, 4)
  ours = np.asarray(jax.vmap(base.quat_to_rpy)(jnp.asarray(bullet["quats"])))
  np.testing.assert_allclose(ours, bullet["rpy"], atol=2e-5)


def test_progress_is_float32_safe(hopper):
  """Potentials are ~6e4 (distance / dt): differencing them in float32 loses ~4e-3 per step.
  Ours, from the same float32 positions, stays within 1e-4 of the exact float64 answer."""
  rng = np.random.default_rng(0)
  target = np.array(hopper.walk_target)
  worst_naive = 0.0
  for _ in range(200):
    old = np.array([rng.uniform(-50, 900), rng.uniform(-5, 5), 1.0], np.float32)
    new = (old + np.array([*rng.uniform(-0.05, 0.05, 2), 0.0])).astype(np.float32)
    dist = lambda p, dtype: np.linalg.norm(target.astype(dtype) - p[:2].astype(dtype))
    exact = (dist(old, np.float64) - dist(new, np.float64)) / hopper.dt
    ours = hopper.progress(jnp.asarray(old), jnp.asarray(new))
    assert float(ours) == pytest.approx(exact, abs=1e-4)
    naive = (np.float32(-dist(new, np.float32) / np.float32(hopper.dt))
             - np.float32(-dist(old, np.float32) / np.float32(hopper.dt)))
    worst_naive = max(worst_naive, abs(naive - exact))
  assert worst_naive > 1e-3  # the naive way would not do


def test_reset_noise_is_uniform_on_joints(hopper, hopper_resets):
  states = hopper_resets(jax.random.split(jax.random.PRNGKey(0), 2000))
  qpos = np.asarray(states.pipeline_state.qpos)
  np.testing.assert_array_equal(qpos[:, :3], 0.0)  # the root is not randomised
  joints = qpos[:, 3:]
  assert joints.min() >= -0.1 and joints.max() <= 0.1
  assert joints.min() < -0.099 and joints.max() > 0.099
  np.testing.assert_allclose(joints.mean(0), 0.0, atol=0.005)
  np.testing.assert_allclose(joints.std(0), 0.2 / np.sqrt(12), rtol=0.05)
  np.testing.assert_array_equal(states.pipeline_state.qvel, 0.0)
  assert hopper.walk_target == (1000.0, 0.0)
