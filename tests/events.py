"""Tasks that go wrong, for the tests, in a module they can import by path (`events:LateNaN`);
the tasks that go right are mjx_hopper.envs.events's."""

import jax.numpy as jnp

from mjx_hopper import envs


class LateNaN(envs.Hopper):
  """A reward that turns NaN once the robot has moved 2 cm along x (mid-episode)."""

  def reward(self, before, after, action):
    terms = super().reward(before, after, action)
    terms["late"] = jnp.where(jnp.abs(after.body_xyz[0]) > 0.02, jnp.nan, 0.0)
    return terms


class Vector(envs.Hopper):
  def reward(self, before, after, action):
    return {**super().reward(before, after, action), "xyz": after.body_xyz}


class NaNAtReset(envs.Hopper):
  def reward(self, before, after, action):
    return {**super().reward(before, after, action), "log": jnp.log(after.body_xyz[2] - 10.0)}


class NotAnEnv:
  pass
