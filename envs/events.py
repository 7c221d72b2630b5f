"""Robolympics events: custom tasks as subclasses of the robots, to train or to copy.

    mjx-hopper train --env mjx_hopper.envs.events:HighJump --env-set height_weight=5.0
    loop.RunConfig(env=events.AntLongJump, episode_steps=200)
"""

from __future__ import annotations

import jax.numpy as jnp

from mjx_hopper.envs.ant import Ant
from mjx_hopper.envs.hopper import Hopper


class HighJump(Hopper):
  """`height_weight` points per step per metre of torso above 1 m; leaning past 45 degrees
  ends it."""

  def __init__(self, height_weight: float = 10.0, episode_steps: int = 300, **kwargs):
    super().__init__(episode_steps=episode_steps, **kwargs)
    self.height_weight = height_weight

  def reward(self, before, after, action):
    terms = super().reward(before, after, action)
    del terms["progress"]
    terms["height"] = self.height_weight * (after.body_xyz[2] - 1.0)
    return terms

  def is_done(self, robot, terms):
    return super().is_done(robot, terms) | (jnp.abs(robot.body_rpy[1]) > jnp.pi / 4)


class AntLongJump(Ant):
  """The Ant's run plus `flight_bonus` per step with no foot on the floor: bounding beats
  walking."""

  def __init__(self, flight_bonus: float = 2.0, **kwargs):
    super().__init__(**kwargs)
    self.flight_bonus = flight_bonus

  def reward(self, before, after, action):
    terms = super().reward(before, after, action)
    terms["flight"] = self.flight_bonus * jnp.all(after.feet_contact == 0)
    return terms
