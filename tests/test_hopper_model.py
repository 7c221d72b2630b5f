"""The Hopper model against PyBullet's HopperBulletEnv: masses, inertias, torques, limits, timing."""

import mujoco
import numpy as np
import pytest

BULLET_PARTS = ("torso", "thigh", "leg", "foot")


def test_link_masses_within_one_percent(hopper, bullet_hopper):
  from mjx_hopper.envs import pybullet_oracle
  bullet = pybullet_oracle.link_masses(bullet_hopper)
  assert sorted(bullet) == sorted(BULLET_PARTS)
  for name, mass in bullet.items():
    ours = hopper.mj_model.body(name).mass[0]
    assert ours == pytest.approx(mass, rel=0.01), name
  assert hopper.mj_model.body_mass.sum() == pytest.approx(15.82, rel=0.01)


def test_inertias_are_bullets(hopper, bullet_hopper):
  client = bullet_hopper._p
  for name in BULLET_PARTS:
    part = bullet_hopper.robot.parts[name]
    info = client.getDynamicsInfo(part.bodies[part.bodyIndex], part.bodyPartIndex)
    np.testing.assert_allclose(hopper.mj_model.body(name).inertia, info[2], rtol=1e-4)


def test_mass_matrix_matches_bullet(hopper, bullet_hopper):
  rng = np.random.default_rng(0)
  model, data = hopper.mj_model, mujoco.MjData(hopper.mj_model)
  body = bullet_hopper.robot.objects[0]
  for _ in range(3):
    q = rng.uniform(-1, 1, model.nq)
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    ours = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, ours)
    theirs = np.array(bullet_hopper._p.calculateMassMatrix(body, list(q)))
    np.testing.assert_allclose(ours, theirs, rtol=1e-4, atol=1e-5)


def test_torques_are_power_times_power_coef(hopper, bullet_hopper):
  robot = bullet_hopper.robot
  expected = [robot.power * j.power_coef for j in robot.ordered_joints]
  assert expected == [75.0, 75.0, 75.0]
  model, data = hopper.mj_model, mujoco.MjData(hopper.mj_model)
  data.ctrl[:] = [1.0, -1.0, 3.0]  # the last is clipped to 1, as PyBullet clips actions
  mujoco.mj_forward(model, data)
  np.testing.assert_allclose(data.qfrc_actuator[hopper._dofadr], [75.0, -75.0, 75.0], rtol=1e-6)


def test_joints_and_limits_in_action_order(hopper, bullet_hopper):
  joints = bullet_hopper.robot.ordered_joints
  assert hopper.joints == tuple(j.joint_name for j in joints)
  for j in joints:
    lower, upper = hopper.mj_model.joint(j.joint_name).range
    assert (lower, upper) == pytest.approx((j.lowerLimit, j.upperLimit), abs=1e-5)


def test_timing_and_planar_root(hopper, bullet_hopper):
  assert hopper.dt == pytest.approx(bullet_hopper.scene.dt)
  assert hopper.n_substeps == bullet_hopper.scene.frame_skip == 4
  assert hopper.mj_model.opt.timestep == pytest.approx(0.0165 / 4)
  model = hopper.mj_model
  root = [model.joint(i) for i in range(3)]
  assert [int(j.type[0]) for j in root] == [mujoco.mjtJoint.mjJNT_SLIDE] * 2 + [
      mujoco.mjtJoint.mjJNT_HINGE]
  np.testing.assert_array_equal(model.jnt_axis[:3], [[1, 0, 0], [0, 0, 1], [0, 1, 0]])
  assert model.nq == model.nv == 6


def test_specs(hopper, bullet_hopper):
  action, obs, reward = hopper.action_spec(), hopper.observation_spec(), hopper.reward_spec()
  assert action.shape == bullet_hopper.action_space.shape == (3,)
  assert obs.shape == bullet_hopper.observation_space.shape == (15,)
  assert reward.shape == ()
  assert {np.dtype(s.dtype) for s in (action, obs, reward)} == {np.dtype(np.float32)}
  np.testing.assert_array_equal(action.minimum, -1.0)
  np.testing.assert_array_equal(action.maximum, 1.0)
  assert repr(action) == ("BoundedArray(shape=(3,), dtype=float32, name='action', "
                          "minimum=[-1. -1. -1.], maximum=[1. 1. 1.])")
  assert repr(obs) == "Array(shape=(15,), dtype=float32, name='observation')"
  spec = hopper.spec()
  assert repr((spec.actions, spec.observations, spec.rewards)) == repr((action, obs, reward))
