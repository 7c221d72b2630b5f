"""Robolympics events: tasks of one's own, as subclasses of the robots, to train or to copy.

    mjx-hopper train --env mjx_hopper.envs.events:HighJump --env-set height_weight=5.0
    loop.RunConfig(env=events.AntLongJump, episode_steps=200)

The notebook (section 7) writes the same events itself, and says how to write a good one.
"""

from __future__ import annotations

import jax.numpy as jnp

from mjx_hopper.envs.ant import Ant
from mjx_hopper.envs.hopper import Hopper


class HighJump(Hopper):
  """The high jump, 300 steps (5 s) by default: no points for going forward; `height_weight`
  points per step for each metre the torso is above 1 m (the Hopper stands at 1.25 m); leaning
  past 45 degrees ends the jump.

  Its terms: alive (+1), height (+2.5 standing, more in the air), electricity_cost,
  joints_at_limit_cost and feet_collision_cost, PyBullet's."""

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
  """The Ant's long jump: its running task (progress toward the target), plus `flight_bonus`
  points for every step that no foot touches the floor, so that bounding beats walking."""

  def __init__(self, flight_bonus: float = 2.0, **kwargs):
    super().__init__(**kwargs)
    self.flight_bonus = flight_bonus

  def reward(self, before, after, action):
    terms = super().reward(before, after, action)
    terms["flight"] = self.flight_bonus * jnp.all(after.feet_contact == 0)
    return terms
