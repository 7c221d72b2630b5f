"""PyBullet's locomotion tasks as jit-compiled, batched MuJoCo MJX environments.

    from mjx_hopper import envs
    env = envs.make("Hopper")
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    state = jax.jit(env.step)(state, jnp.zeros(env.action_size))

A task of your own is a subclass of a robot (see `mjx_hopper.envs.tasks`).
"""

from mjx_hopper.envs.ant import Ant
from mjx_hopper.envs.base import REWARD_TERMS, LocomotionEnv, Robot, State
from mjx_hopper.envs.half_cheetah import HalfCheetah
from mjx_hopper.envs.hopper import Hopper
from mjx_hopper.envs.humanoid import Humanoid
from mjx_hopper.envs.specs import Array, BoundedArray, EnvironmentSpec
from mjx_hopper.envs import tasks
from mjx_hopper.envs.tasks import (check_task, list_envs, make, register, robot_of, settings_of,
                                   task_class, task_id, task_settings)
from mjx_hopper.envs.walker2d import Walker2D
from mjx_hopper.envs.wrappers import AutoReset

tasks.BUILT_IN = ("Hopper", "Walker2D", "HalfCheetah", "Ant", "Humanoid")
for _robot in (Hopper, Walker2D, HalfCheetah, Ant, Humanoid):
  register(_robot.__name__, _robot)

__all__ = ["Ant", "Array", "AutoReset", "BoundedArray", "EnvironmentSpec", "HalfCheetah", "Hopper",
           "Humanoid", "LocomotionEnv", "REWARD_TERMS", "Robot", "State", "Walker2D", "check_task",
           "list_envs", "make", "register", "robot_of", "settings_of", "task_class", "task_id",
           "task_settings", "tasks"]
