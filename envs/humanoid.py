"""Humanoid: PyBullet's HumanoidBulletEnv, a 17-joint biped with a free-floating torso."""

import jax
import jax.numpy as jnp

from mjx_hopper.envs.base import LocomotionEnv, Robot


class Humanoid(LocomotionEnv):
  """Walk toward (1000, 0). Observation 44, action 17; alive gives +2 and electricity costs
  4.25 times the other robots'."""

  xml_file = "humanoid.xml"
  joints = ("abdomen_z", "abdomen_y", "abdomen_x",
            "right_hip_x", "right_hip_z", "right_hip_y", "right_knee",
            "left_hip_x", "left_hip_z", "left_hip_y", "left_knee",
            "right_shoulder1", "right_shoulder2", "right_elbow",
            "left_shoulder1", "left_shoulder2", "left_elbow")
  power = 0.41
  # PyBullet's Humanoid applies its own `motor_power` list, not the joints' power_coef.
  power_coefs = ((100.0,) * 3 + (100.0, 100.0, 300.0, 200.0) * 2 + (75.0,) * 6)
  feet = ("right_foot", "left_foot")
  # Only the legs touch the floor. While alive (torso centre of mass above 0.78 m) the torso,
  # head, waist, pelvis and upper arms cannot reach it; the forearms can, in rare poses, and
  # pass through it (docs/fidelity.md). A task that lets the robot lie, crawl or lean on its
  # hands sets floor_bodies = None.
  floor_bodies = ("right_thigh", "right_shin", "right_foot", "left_thigh", "left_shin",
                  "left_foot")
  initial_z = 0.8
  electricity_cost = 4.25 * -2.0
  stall_torque_cost = 4.25 * -0.1

  def alive_bonus(self, z: jax.Array, pitch: jax.Array, robot: Robot) -> jax.Array:
    return jnp.where(z > 0.78, 2.0, -1.0)
