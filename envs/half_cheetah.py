"""HalfCheetah: PyBullet's HalfCheetahBulletEnv, a planar runner that never terminates early."""

import jax
import jax.numpy as jnp

from mjx_hopper.envs.base import LocomotionEnv, Robot


class HalfCheetah(LocomotionEnv):
  """Run toward (1000, 0). Observation 26, action 6; never terminates."""

  xml_file = "half_cheetah.xml"
  joints = ("bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot")
  power = 0.9
  power_coefs = (120.0, 90.0, 60.0, 140.0, 60.0, 30.0)
  feet = ("ffoot", "fshin", "fthigh", "bfoot", "bshin", "bthigh")  # all six leg links
  initial_z = 0.7

  def alive_bonus(self, z: jax.Array, pitch: jax.Array, robot: Robot) -> jax.Array:
    shin_or_thigh_down = robot.feet_contact[jnp.array([1, 2, 4, 5])].any()
    return jnp.where((jnp.abs(pitch) < 1.0) & ~shin_or_thigh_down, 1.0, -1.0)

  def is_done(self, robot: Robot, terms: dict[str, jax.Array]) -> jax.Array:
    return jnp.zeros((), bool)
