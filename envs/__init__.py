"""PyBullet's locomotion tasks as jit-compiled, batched MuJoCo MJX environments.

    from mjx_hopper import envs
    env = envs.make("Hopper")
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    state = jax.jit(env.step)(state, jnp.zeros(env.action_size))

A task of your own is a subclass of a robot; `mjx_hopper.envs.tasks` says how one is named
(a class, a `module:Class` path, or a name given with `register`) and what a run records of it.
`to_gymnasium(task, num_envs=None)` opens any task to Gymnasium (the `gymnasium` extra).
"""

from mjx_hopper.envs.ant import Ant
from mjx_hopper.envs.base import PHYSICS, REWARD_TERMS, LocomotionEnv, Robot, State
from mjx_hopper.envs.half_cheetah import HalfCheetah
from mjx_hopper.envs.hopper import Hopper
from mjx_hopper.envs.humanoid import Humanoid
from mjx_hopper.envs.specs import Array, BoundedArray, EnvironmentSpec
from mjx_hopper.envs import tasks
from mjx_hopper.envs.tasks import (check_task, list_envs, make, register, robot_of, settings_of,
                                   task_class, task_id, task_settings)
from mjx_hopper.envs.walker2d import Walker2D
from mjx_hopper.envs.wrappers import AutoReset, EpisodeStarts

tasks.BUILT_IN = ("Hopper", "Walker2D", "HalfCheetah", "Ant", "Humanoid")
for _robot in (Hopper, Walker2D, HalfCheetah, Ant, Humanoid):
  register(_robot.__name__, _robot)



def __getattr__(name: str):
  """`to_gymnasium`, imported when first used: Gymnasium is an optional extra."""
  if name == "to_gymnasium":
    from mjx_hopper.envs.gymnasium import to_gymnasium
    return to_gymnasium
  raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Ant", "Array", "AutoReset", "BoundedArray", "EnvironmentSpec", "EpisodeStarts",
           "HalfCheetah", "Hopper", "Humanoid", "LocomotionEnv", "PHYSICS", "REWARD_TERMS", "Robot",
           "State", "Walker2D", "check_task", "list_envs", "make", "register", "robot_of",
           "settings_of", "task_class", "task_id", "task_settings", "tasks", "to_gymnasium"]
