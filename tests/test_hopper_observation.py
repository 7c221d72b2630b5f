"""Observations, body positions and speeds against PyBullet's `calc_state`, state for state."""

import jax
import jax.numpy as jnp
import numpy as np
import pybullet
import pytest

from mjx_hopper.envs import base, pybullet_oracle

ROOT = ["ignore1", "ignore2", "ignore3"]  # Bullet's names of the slide x, slide z, hinge y root
JOINTS = ["thigh_joint", "leg_joint", "foot_joint"]


def random_states(n, seed, airborne=False):
  rng = np.random.default_rng(seed)
  for _ in range(n):
    root = rng.uniform(-0.5, 0.5, 3)
    if airborne:
      root[1] = 0.6
    q = np.concatenate([root, rng.uniform([-2.4, -2.4, -0.7], [0.0, 0.0, 0.7])])
    yield q, rng.uniform(-2, 2, 6)


def bullet_state(env, q, v):
  names = ROOT + JOINTS
  return pybullet_oracle.set_state(env, dict(zip(names, q)), dict(zip(names, v)))


@pytest.fixture(scope="module")
def init_state(hopper):
  return jax.jit(hopper.init_state)


def test_reset_observation_matches_bullet(hopper, bullet_hopper, init_state):
  for seed in range(5):
    bullet_hopper.seed(seed)
    bullet_obs = bullet_hopper.reset()
    angles = [j.get_position() for j in bullet_hopper.robot.ordered_joints]
    state = init_state(jnp.array([0, 0, 0, *angles]), jnp.zeros(6))
    np.testing.assert_allclose(state.obs, bullet_obs, atol=1e-5)
    assert state.obs.dtype == jnp.float32


def test_observation_matches_bullet_at_random_states(hopper, bullet_hopper, init_state):
  for q, v in random_states(20, seed=1):
    bullet_obs = bullet_state(bullet_hopper, q, v)
    state = init_state(q, v)
    np.testing.assert_allclose(state.obs, bullet_obs, atol=1e-5)
    robot = state.info["robot"]
    np.testing.assert_allclose(robot.body_xyz, bullet_hopper.robot.body_xyz, atol=1e-5)
    np.testing.assert_allclose(hopper.torso_speed(state), bullet_hopper.robot_body.speed(),
                               atol=1e-5)
    positions = hopper.body_positions(state)
    assert sorted(positions) == ["foot", "leg", "thigh", "torso"]
    for name, xyz in positions.items():
      np.testing.assert_allclose(xyz, bullet_hopper.robot.parts[name].pose().xyz(), atol=1e-5)


def test_one_step_matches_bullet(hopper, bullet_hopper, init_state, hopper_step):
  """After a control step PyBullet reports poses one substep old: so must we."""
  rng = np.random.default_rng(2)
  for airborne, (q, v) in [(True, s) for s in random_states(4, 3, airborne=True)] + [
      (False, s) for s in random_states(4, 4)]:
    action = rng.uniform(-1, 1, 3)
    bullet_state(bullet_hopper, q, v)
    bullet_hopper.potential = bullet_hopper.robot.calc_potential()
    bullet_obs, _, _, _ = bullet_hopper.step(action)
    state = hopper_step(init_state(q, v), jnp.asarray(action, jnp.float32))
    progress = bullet_hopper.rewards[1]
    assert float(state.metrics["progress"]) == pytest.approx(progress, rel=0.01, abs=0.01)
    if airborne:  # no contact: only the integrators differ
      speed = np.zeros(15, bool)
      speed[3:6] = True  # Bullet takes the link speed from a part-updated pose: see fidelity.md
      np.testing.assert_allclose(state.obs[~speed], bullet_obs[~speed], atol=0.005)
      np.testing.assert_allclose(state.obs[speed], bullet_obs[speed], atol=0.04)


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
  rng = np.random.default_rng(0)
  quats = rng.normal(size=(200, 4))
  quats /= np.linalg.norm(quats, axis=1, keepdims=True)
  ours = np.asarray(jax.vmap(base.quat_to_rpy)(jnp.asarray(quats)))
  for q, rpy in zip(quats, ours):
    w, x, y, z = q
    np.testing.assert_allclose(rpy, pybullet.getEulerFromQuaternion([x, y, z, w]), atol=2e-5)


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


def test_reset_noise_is_uniform_on_joints(hopper, hopper_reset):
  states = jax.vmap(hopper_reset)(jax.random.split(jax.random.PRNGKey(0), 2000))
  qpos = np.asarray(states.pipeline_state.qpos)
  np.testing.assert_array_equal(qpos[:, :3], 0.0)  # the root is not randomised
  joints = qpos[:, 3:]
  assert joints.min() >= -0.1 and joints.max() <= 0.1
  assert joints.min() < -0.099 and joints.max() > 0.099
  np.testing.assert_allclose(joints.mean(0), 0.0, atol=0.005)
  np.testing.assert_allclose(joints.std(0), 0.2 / np.sqrt(12), rtol=0.05)
  np.testing.assert_array_equal(states.pipeline_state.qvel, 0.0)
  assert hopper.walk_target == (1000.0, 0.0)
