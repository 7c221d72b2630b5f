"""PyBullet's locomotion tasks as jit-compiled, batched MuJoCo MJX environments.

    from mjx_hopper import envs
    env = envs.make("Hopper")
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    state = jax.jit(env.step)(state, jnp.zeros(env.action_size))
"""

from mjx_hopper.envs.ant import Ant
from mjx_hopper.envs.base import REWARD_TERMS, LocomotionEnv, Robot, State
from mjx_hopper.envs.half_cheetah import HalfCheetah
from mjx_hopper.envs.hopper import Hopper
from mjx_hopper.envs.humanoid import Humanoid
from mjx_hopper.envs.specs import Array, BoundedArray, EnvironmentSpec
from mjx_hopper.envs.walker2d import Walker2D
from mjx_hopper.envs.wrappers import AutoReset

_REGISTRY: dict[str, type[LocomotionEnv]] = {
    cls.__name__: cls for cls in (Hopper, Walker2D, HalfCheetah, Ant, Humanoid)}


def list_envs() -> list[str]:
  """The ids `make` accepts."""
  return sorted(_REGISTRY)


def make(env_id: str, **kwargs) -> LocomotionEnv:
  """Builds the env `env_id` (see `list_envs()`); kwargs go to its constructor."""
  if env_id not in _REGISTRY:
    raise ValueError(f"unknown env id {env_id!r}; valid ids are {list_envs()}")
  return _REGISTRY[env_id](**kwargs)


__all__ = ["Ant", "Array", "AutoReset", "BoundedArray", "EnvironmentSpec", "HalfCheetah", "Hopper",
           "Humanoid", "LocomotionEnv", "REWARD_TERMS", "Robot", "State", "Walker2D", "list_envs",
           "make"]
