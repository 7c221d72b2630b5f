"""Robolympics events for the tests: tasks of one's own, in a module the tests (and the CLI
processes they start) can import by path, as `events:HighJump`."""

import jax.numpy as jnp

from mjx_hopper import envs


class HighJump(envs.Hopper):
  """The notebook's high jump, with a setting: points for the torso's height, none for going
  forward, and leaning past 45 degrees ends the jump."""

  def __init__(self, height_weight: float = 10.0, **kwargs):
    super().__init__(**kwargs)
    self.height_weight = height_weight

  def reward(self, before, after, action):
    terms = super().reward(before, after, action)
    del terms["progress"]
    terms["height"] = self.height_weight * (after.body_xyz[2] - 1.0)
    return terms

  def is_done(self, robot, terms):
    return super().is_done(robot, terms) | (jnp.abs(robot.body_rpy[1]) > jnp.pi / 4)


class AntLongJump(envs.Ant):
  """Forward progress counts double while no foot touches the floor."""

  def reward(self, before, after, action):
    terms = super().reward(before, after, action)
    airborne = jnp.all(after.feet_contact == 0)
    terms["flight"] = jnp.where(airborne, terms["progress"], 0.0)
    return terms


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
