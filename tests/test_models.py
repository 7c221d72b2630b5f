"""Each robot's model against PyBullet's: masses, inertias, torques, limits, timing, specs, as
tests/record_oracle.py recorded them in tests/oracle/."""

import itertools

import mujoco
import numpy as np
import pytest

from conftest import ROBOTS, make_env, oracle
from mjx_hopper import envs

TOTAL_MASS = {"Hopper": 15.82, "Walker2D": 23.6772, "HalfCheetah": 38.1878, "Ant": 182.176,
              "Humanoid": 42.116}  # kg, read from PyBullet 3.2.7
SIZES = {"Hopper": (15, 3), "Walker2D": (22, 6), "HalfCheetah": (26, 6), "Ant": (28, 8),
         "Humanoid": (44, 17)}


@pytest.mark.parametrize("robot", ROBOTS)
def test_link_masses_within_one_percent(robot):
  env, bullet = make_env(robot), oracle(robot)
  theirs = dict(zip(bullet["parts"], bullet["masses"]))
  ours = {env.mj_model.body(i).name: env.mj_model.body_mass[i]
          for i in range(1, env.mj_model.nbody)}
  assert sorted(ours) == sorted(theirs)
  for name, mass in theirs.items():
    assert ours[name] == pytest.approx(mass, rel=0.01), name
  assert sum(ours.values()) == pytest.approx(TOTAL_MASS[robot], rel=0.01)


@pytest.mark.parametrize("robot", ROBOTS)
def test_inertias_are_bullets(robot):
  env, bullet = make_env(robot), oracle(robot)
  assert len(bullet["inertias"]) == len(bullet["parts"]) > 0
  for name, inertia in zip(bullet["parts"], bullet["inertias"]):
    np.testing.assert_allclose(env.mj_model.body(name).inertia, inertia, rtol=1e-4,
                               err_msg=name)  # where it sits: the mass-matrix test


@pytest.mark.parametrize("robot", ROBOTS)
def test_joint_space_mass_matrix_matches_bullet(robot):
  """At 3 random joint angles (the root at rest pose): the whole matrix for planar robots, the
  joints' block for free-floating ones (Bullet orders its base coordinates differently). The
  bodies' part only: the Humanoid's hinges add an armature of their own (humanoid.xml)."""
  env, bullet = make_env(robot), oracle(robot)
  model, data = env.mj_model, mujoco.MjData(env.mj_model)
  free = env._root == "free"
  assert len(bullet["mass_matrix"]) == 3
  for qpos, theirs in zip(bullet["mass_matrix_qpos"], bullet["mass_matrix"]):
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    ours = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, ours)
    ours -= np.diag(model.dof_armature)
    if free:
      ours, theirs = ours[6:, 6:], theirs[6:, 6:]
    np.testing.assert_allclose(ours, theirs, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("robot", ROBOTS)
def test_torques_are_power_times_power_coef(robot):
  """Bullet's torque at |a| = 1 is power times what apply_action multiplies by (the Humanoid's
  own motor_power list, else each joint's power_coef)."""
  env, expected = make_env(robot), oracle(robot)["torques"]
  model, data = env.mj_model, mujoco.MjData(env.mj_model)
  data.ctrl[:] = np.where(np.arange(model.nu) % 2, -1.0, 3.0)  # 3 is clipped to 1
  mujoco.mj_forward(model, data)
  signs = np.where(np.arange(model.nu) % 2, -1.0, 1.0)
  np.testing.assert_allclose(data.qfrc_actuator[env._dofadr], signs * expected, rtol=1e-6)


@pytest.mark.parametrize("robot", ROBOTS)
def test_joints_and_limits_in_action_order(robot):
  env, bullet = make_env(robot), oracle(robot)
  assert env.joints == tuple(bullet["joints"])
  for name, limits in zip(bullet["joints"], bullet["joint_limits"]):
    lower, upper = env.mj_model.joint(name).range
    assert (lower, upper) == pytest.approx(tuple(limits), abs=1e-5)


@pytest.mark.parametrize("robot", ROBOTS)
def test_timing_root_and_feet(robot):
  env, bullet = make_env(robot), oracle(robot)
  assert env.dt == pytest.approx(bullet["dt"])
  assert env.n_substeps == bullet["frame_skip"] == 4
  assert env.mj_model.opt.timestep == pytest.approx(0.0165 / 4)
  assert env._root == ("free" if robot in ("Ant", "Humanoid") else "planar")
  assert env.feet == tuple(bullet["feet"])
  assert env.initial_z == pytest.approx(bullet["initial_z"], abs=1e-6)
  assert env.electricity_cost == bullet["electricity_cost"]
  assert env.stall_torque_cost == pytest.approx(bullet["stall_torque_cost"])
  assert env._parts.count == bullet["part_count"]


@pytest.mark.parametrize("robot", ROBOTS)
def test_specs(robot):
  env, bullet = make_env(robot), oracle(robot)
  obs_size, act_size = SIZES[robot]
  action, obs, reward = env.action_spec(), env.observation_spec(), env.reward_spec()
  assert action.shape == (bullet["action_size"],) == (act_size,)
  assert obs.shape == (bullet["observation_size"],) == (obs_size,)
  assert reward.shape == ()
  assert {np.dtype(s.dtype) for s in (action, obs, reward)} == {np.dtype(np.float32)}
  np.testing.assert_array_equal(action.minimum, -1.0)
  np.testing.assert_array_equal(action.maximum, 1.0)
  assert repr(obs) == f"Array(shape=({obs_size},), dtype=float32, name='observation')"
  spec = env.spec()
  assert repr((spec.actions, spec.observations, spec.rewards)) == repr((action, obs, reward))


def test_hopper_action_spec_reads_well(hopper):
  assert repr(hopper.action_spec()) == (
      "BoundedArray(shape=(3,), dtype=float32, name='action', "
      "minimum=[-1. -1. -1.], maximum=[1. 1. 1.])")


def _farthest_reach(model, data, geom, torso):
  """How far the geom's surface reaches from the torso's centre of mass in this pose (m)."""
  centre, size = data.geom_xpos[geom], model.geom_size[geom]
  ends = [centre]
  if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_CAPSULE:
    axis = data.geom_xmat[geom].reshape(3, 3)[:, 2] * size[1]
    ends = [centre + axis, centre - axis]
  return max(np.linalg.norm(e - data.xipos[torso]) for e in ends) + size[0]


def test_humanoid_floor_contacts_are_where_the_floor_is_in_reach():
  """Alive means the torso's centre of mass is above 0.78 m, and only the legs touch the floor.
  The torso, head, waist, pelvis and upper arms stay less than 0.78 m from that centre in every
  pose of the joints between them (a grid over their ranges), so they cannot touch the floor
  while alive. The forearms reach 0.90 m: in rare poses they pass up to 0.12 m through the floor
  (docs/fidelity.md)."""
  env = make_env("Humanoid")
  model, data = env.mj_model, mujoco.MjData(env.mj_model)
  torso = model.body("torso").id
  dropped = {model.geom(g).name for g in range(1, model.ngeom) if model.geom_contype[g] == 0}
  forearms = {"right_larm", "right_hand", "left_larm", "left_hand"}
  assert dropped == {"torso1", "head", "uwaist", "lwaist", "butt", "right_uarm1",
                     "left_uarm1"} | forearms
  reach = {}
  for name in dropped:
    g = model.geom(name).id
    body, chain = model.geom_bodyid[g], []
    while body != torso:
      chain += [j for j in range(model.njnt) if model.jnt_bodyid[j] == body]
      body = model.body_parentid[body]
    reach[name] = 0.0
    for values in itertools.product(*[np.linspace(*model.jnt_range[j], 9) for j in chain]):
      data.qpos[:] = model.qpos0
      data.qpos[model.jnt_qposadr[chain]] = values
      mujoco.mj_kinematics(model, data)
      reach[name] = max(reach[name], _farthest_reach(model, data, g, torso))
  for name in dropped - forearms:
    assert reach[name] < 0.78, (name, reach[name])
  for name in forearms:
    assert 0.8 < reach[name] < 0.91, (name, reach[name])


def test_floor_bodies_choose_which_parts_touch_the_floor():
  class Crawler(envs.Humanoid):
    floor_bodies = None
  model = Crawler().mj_model
  assert (model.geom_contype[1:] != 0).all() and (model.geom_conaffinity[1:] != 0).all()

  class Typo(envs.Humanoid):
    floor_bodies = ("right_foot", "nose")
  with pytest.raises(ValueError, match=r"Typo.floor_bodies names \['nose'\], which humanoid.xml "
                                       r"lacks; its bodies are \['torso', "):
    Typo()
