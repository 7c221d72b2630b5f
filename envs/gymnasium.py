"""Any task as a Gymnasium environment, for Stable-Baselines3, CleanRL and the like.

    from mjx_hopper import envs
    env = envs.to_gymnasium("Hopper")                   # a gymnasium.Env
    vec = envs.to_gymnasium("Hopper", num_envs=256)     # a gymnasium.vector.VectorEnv

Steps are jit-compiled (a vector env's batched with vmap and spread over the local devices), and
observations, rewards and flags come out as NumPy. Termination and truncation (the time limit)
are separate flags. The vector env resets an ended episode in the same step
(`AutoresetMode.SAME_STEP`): the returned observation is the new episode's first, and
`info["final_obs"]` holds the ended one's last (where `info["_final_obs"]` is True).

Seeds follow the JAX env: `reset(seed=s)` starts the episode of `env.reset(PRNGKey(s))`, and a
vector env's `reset(seed=s)` those of `jax.vmap(AutoReset(env).reset)(split(PRNGKey(s), n))`.

Importing this module registers the robots in Gymnasium's registry as "mjx_hopper/<robot>-v0":

    gymnasium.make("mjx_hopper.envs.gymnasium:mjx_hopper/Hopper-v0", episode_steps=300)
    gymnasium.make_vec("mjx_hopper/Hopper-v0", num_envs=256)   # once this module is imported
"""

from __future__ import annotations

from typing import Any

try:
  import gymnasium
  from gymnasium.vector import AutoresetMode
  from gymnasium.vector.utils import batch_space
except ImportError:
  raise ImportError("mjx_hopper.envs.to_gymnasium needs Gymnasium (>= 1.1): in the "
                    "mjx_hopper checkout, pip install -e '.[gymnasium]'") from None
import jax
import numpy as np

from mjx_hopper.process import parallel
from mjx_hopper.envs.base import LocomotionEnv
from mjx_hopper.envs.tasks import BUILT_IN, make

NAMESPACE = "mjx_hopper"
from mjx_hopper.envs.wrappers import AutoReset


def to_gymnasium(task: Any, num_envs: int | None = None, render_mode: str | None = None,
                 **settings) -> gymnasium.Env | gymnasium.vector.VectorEnv:
  """The task (a robot's name, a registered name, a `module:Class` path, a class, or an
  instance) as a `gymnasium.Env`, or with `num_envs`, a `gymnasium.vector.VectorEnv` of that
  many envs. `settings` are the task's constructor settings (episode_steps, ...), for a task
  not given as an instance. `render_mode` "rgb_array" lets the single env render frames."""
  if isinstance(task, LocomotionEnv):
    if settings:
      raise ValueError(f"settings {sorted(settings)} are for a task given by name or class; "
                       f"{type(task).__name__} is an instance, built with its own")
    env = task
  else:
    env = make(task, **settings)
  if num_envs is None:
    return GymnasiumEnv(env, render_mode)
  if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
    raise ValueError(f"num_envs must be None (one env) or an integer >= 1, got {num_envs!r}")
  if render_mode is not None:
    raise ValueError(f"render_mode {render_mode!r} is for the single env (num_envs=None)")
  return GymnasiumVectorEnv(env, num_envs)


def _spaces(env: LocomotionEnv) -> tuple[gymnasium.spaces.Box, gymnasium.spaces.Box]:
  """(observation space, action space) of one env: float32, observations in [-5, 5] (where
  `LocomotionEnv.observation` clips them, as PyBullet does) and actions in [-1, 1]."""
  obs = gymnasium.spaces.Box(-5.0, 5.0, (env.observation_size,), np.float32)
  action = gymnasium.spaces.Box(-1.0, 1.0, (env.action_size,), np.float32)
  return obs, action


def _key(seed, np_random: np.random.Generator) -> jax.Array:
  """PRNGKey(seed), or without a seed, a key drawn from the env's seeded NumPy generator."""
  return jax.random.PRNGKey(int(np_random.integers(2**31)) if seed is None else seed)


def _advance(door, action) -> tuple:
  """Steps `door` (either Gymnasium env here) by `action`, checked against its action space;
  returns the step's outputs on the host."""
  if door._state is None:
    raise RuntimeError("call reset() before step()")
  action = np.asarray(action, np.float32)
  name, shape = type(door.env).__name__, door.action_space.shape
  if action.shape != shape:
    raise ValueError(f"{name} takes actions of shape {shape}, got {action.shape}")
  bad = ~np.isfinite(action)
  if bad.any():
    at = tuple(int(i) for i in np.argwhere(bad)[0])
    more = f" (and {bad.sum() - 1} more)" if bad.sum() > 1 else ""
    raise ValueError(f"{name} takes finite actions, got {action[at]} at index {at}{more}")
  door._state, out = door._step(door._state, action)
  return jax.device_get(out)


class GymnasiumEnv(gymnasium.Env):
  """One env of a task, stepped by a jit-compiled `env.step`."""

  def __init__(self, env: LocomotionEnv, render_mode: str | None = None):
    if render_mode not in (None, "rgb_array"):
      raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
    self.env, self.render_mode = env, render_mode
    self.observation_space, self.action_space = _spaces(env)
    self.metadata = {"render_modes": ["rgb_array"], "render_fps": 1 / env.dt}
    self._reset = jax.jit(env.reset)
    self._step = jax.jit(lambda state, action: _outputs(env.step(state, action)))
    self._state = None

  def reset(self, *, seed: int | None = None, options: dict | None = None):
    super().reset(seed=seed)
    self._state = self._reset(_key(seed, self.np_random))
    return np.asarray(self._state.obs), {}

  def step(self, action):
    obs, reward, terminated, truncated, terms = _advance(self, action)
    return (obs, float(reward), bool(terminated), bool(truncated),
            {"reward_terms": {k: float(v) for k, v in terms.items()}})

  def render(self):
    if self.render_mode != "rgb_array" or self._state is None:
      return None
    return self.env.render(np.asarray(self._state.pipeline_state.qpos))


def _outputs(state) -> tuple[Any, tuple]:
  """(state, (obs, reward, terminated, truncated, reward terms)) after a step."""
  truncated = state.info["truncation"] > 0
  terminated = (state.done > 0) & ~truncated
  return state, (state.obs, state.reward, terminated, truncated, state.metrics)


class GymnasiumVectorEnv(gymnasium.vector.VectorEnv):
  """`num_envs` envs of a task, auto-resetting in the same step, stepped together by one
  compiled call spread over the local devices."""

  def __init__(self, env: LocomotionEnv, num_envs: int):
    self.env, self.num_envs = env, num_envs
    self.single_observation_space, self.single_action_space = _spaces(env)
    self.observation_space = batch_space(self.single_observation_space, num_envs)
    self.action_space = batch_space(self.single_action_space, num_envs)
    self.metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_fps": 1 / env.dt}
    auto = AutoReset(env)

    def step(state, action):
      state = jax.vmap(auto.step)(state, action)
      truncated = state.info["truncation"] > 0
      ended = state.done > 0
      return state, (state.obs, state.reward, ended & ~truncated, truncated,
                     state.info["final_obs"])

    self._reset = jax.jit(lambda keys: parallel.shard(jax.vmap(auto.reset)(keys)))
    self._step = jax.jit(parallel.per_device(step, num_envs), donate_argnums=0)
    self._state = None

  def reset(self, *, seed: int | list | None = None, options: dict | None = None):
    if isinstance(seed, (list, tuple)):
      if len(seed) != self.num_envs:
        raise ValueError(f"seed takes an integer or {self.num_envs} of them, got {len(seed)}")
      super().reset(seed=seed[0])
      keys = jax.numpy.stack([_key(s, self.np_random) for s in seed])
    else:
      super().reset(seed=seed)
      keys = jax.random.split(_key(seed, self.np_random), self.num_envs)
    self._state = self._reset(keys)
    return np.asarray(self._state.obs), {}

  def step(self, actions):
    obs, reward, terminated, truncated, final_obs = _advance(self, actions)
    info = {}
    ended = terminated | truncated
    if ended.any():
      final = np.full(self.num_envs, None, dtype=object)
      for i in np.flatnonzero(ended):
        final[i] = final_obs[i]
      info = {"final_obs": final, "_final_obs": ended}
    return obs, reward, terminated, truncated, info


def register() -> None:
  """Registers each robot as "mjx_hopper/<robot>-v0" in Gymnasium's registry, for
  `gymnasium.make` (its keywords are `to_gymnasium`'s settings and render_mode) and
  `gymnasium.make_vec` (the vector env, in one compiled call). The time limit is the task's own
  `episode_steps`: no TimeLimit wrapper is added."""
  for robot in BUILT_IN:
    env_id = f"{NAMESPACE}/{robot}-v0"
    if env_id not in gymnasium.registry:
      gymnasium.register(env_id, entry_point=f"{__name__}:to_gymnasium",
                         vector_entry_point=f"{__name__}:to_gymnasium", kwargs={"task": robot})


register()
