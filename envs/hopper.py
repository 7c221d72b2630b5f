"""Hopper: PyBullet's HopperBulletEnv, a one-legged planar hopper."""

import jax
import jax.numpy as jnp

from mjx_hopper.envs.base import LocomotionEnv, Robot


class Hopper(LocomotionEnv):
  """Hop toward (1000, 0). Observation 15, action 3, 75 Nm per joint at |a| = 1."""

  xml_file = "hopper.xml"
  joints = ("thigh_joint", "leg_joint", "foot_joint")
  power = 0.75
  power_coefs = (100.0, 100.0, 100.0)
  feet = ("foot",)
  initial_z = 1.25

  def alive_bonus(self, z: jax.Array, pitch: jax.Array, robot: Robot) -> jax.Array:
    return jnp.where((z > 0.8) & (jnp.abs(pitch) < 1.0), 1.0, -1.0)
