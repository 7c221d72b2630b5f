"""Walker2D: PyBullet's Walker2DBulletEnv, a planar biped."""

import jax
import jax.numpy as jnp

from mjx_hopper.envs.base import LocomotionEnv, Robot


class Walker2D(LocomotionEnv):
  """Walk toward (1000, 0). Observation 22, action 6; 40 Nm at hips and knees, 12 at ankles."""

  xml_file = "walker2d.xml"
  joints = ("thigh_joint", "leg_joint", "foot_joint",
            "thigh_left_joint", "leg_left_joint", "foot_left_joint")
  power = 0.4
  power_coefs = (100.0, 100.0, 30.0, 100.0, 100.0, 30.0)
  feet = ("foot", "foot_left")
  initial_z = 1.25

  def alive_bonus(self, z: jax.Array, pitch: jax.Array, robot: Robot) -> jax.Array:
    return jnp.where((z > 0.8) & (jnp.abs(pitch) < 1.0), 1.0, -1.0)
