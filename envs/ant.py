"""Ant: PyBullet's AntBulletEnv, a four-legged walker with a free-floating torso."""

import jax
import jax.numpy as jnp

from mjx_hopper.envs.base import LocomotionEnv, Robot


class Ant(LocomotionEnv):
  """Walk toward (1000, 0). Observation 28, action 8, 250 Nm per joint at |a| = 1."""

  xml_file = "ant.xml"
  joints = ("hip_1", "ankle_1", "hip_2", "ankle_2", "hip_3", "ankle_3", "hip_4", "ankle_4")
  power = 2.5
  power_coefs = (100.0,) * 8
  feet = ("front_left_foot", "front_right_foot", "left_back_foot", "right_back_foot")
  initial_z = 0.75

  def alive_bonus(self, z: jax.Array, pitch: jax.Array, robot: Robot) -> jax.Array:
    return jnp.where(z > 0.26, 1.0, -1.0)
