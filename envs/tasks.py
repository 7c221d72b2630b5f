"""Naming a task: a built-in robot, a registered name, or a `LocomotionEnv` subclass (a class,
an instance or a `module:Class` path).

A run records its task's id and settings, so a checkpoint finds its task again:

    envs.task_id(HighJump)                          # 'my_events:HighJump'
    envs.task_settings(HighJump, {"height_weight": 5.0})
    # {'episode_steps': 1000, 'height_weight': 5.0}
    envs.make("my_events:HighJump", episode_steps=300)

A class defined in `__main__` (a notebook, a script) is found only where it is defined;
elsewhere pass the class again or move it to a module.
"""

from __future__ import annotations

import importlib
import inspect
import json
import sys
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_hopper.settings.fields import convert
from mjx_hopper.envs.base import LocomotionEnv

_REGISTRY: dict[str, type[LocomotionEnv]] = {}
# Classes given by object in this process, by id: a class defined in a notebook cell or inside
# a function is found again by its id (after `dataclasses.replace` of a RunConfig, say).
_SEEN: dict[str, type[LocomotionEnv]] = {}
BUILT_IN: tuple[str, ...] = ()  # the five robots, set by envs/__init__.py


def register(name: str, cls: type[LocomotionEnv]) -> None:
  """Makes `name` a task name; a process resuming its checkpoints must register it too."""
  _check_class(cls, repr(cls))
  if not isinstance(name, str) or not name or ":" in name:
    raise ValueError(f"a task name is a non-empty string without ':', got {name!r}")
  if name in BUILT_IN and name in _REGISTRY and _REGISTRY[name] is not cls:
    raise ValueError(f"{name!r} is a built-in robot; register {cls.__name__} under another name")
  _REGISTRY[name] = cls


def list_envs() -> list[str]:
  """The task names `make` accepts: the built-in robots and any registered ones."""
  return sorted(_REGISTRY)


def _check_class(cls, given: str) -> None:
  if not (isinstance(cls, type) and issubclass(cls, LocomotionEnv)):
    raise ValueError(f"{given} is not a LocomotionEnv subclass (a robot of envs.list_envs() or "
                     "a subclass of one)")
  if inspect.isabstract(cls) or not hasattr(cls, "xml_file"):
    raise ValueError(f"{given} is not a robot: subclass one of {list(BUILT_IN)}")


def task_class(spec: Any) -> type[LocomotionEnv]:
  """The class of a task given as a name, a `module:Class` path, a class or an instance."""
  if isinstance(spec, LocomotionEnv):
    spec = type(spec)
  if isinstance(spec, type):
    _check_class(spec, spec.__name__)
    _SEEN[task_id(spec)] = spec
    return spec
  if not isinstance(spec, str):
    raise ValueError(f"a task is a name, a 'module:Class' path, a LocomotionEnv subclass or an "
                     f"instance of one, got {spec!r}")
  if spec in _REGISTRY:
    return _REGISTRY[spec]
  if spec in _SEEN:
    return _SEEN[spec]
  if ":" not in spec:
    raise ValueError(f"unknown env {spec!r}; valid envs are {list_envs()}, a registered name "
                     "(envs.register), or a subclass as 'module:Class'")
  module_name, _, qualname = spec.partition(":")
  if module_name == "__main__" and isinstance(getattr(sys.modules["__main__"], qualname, None),
                                              type):
    return task_class(getattr(sys.modules["__main__"], qualname))  # the notebook defined it
  if module_name == "__main__" or "<locals>" in qualname:
    raise ValueError(f"the task {spec!r} was defined in a notebook or a script (or inside a "
                     "function), which this process cannot import; pass the class itself again "
                     "(RunConfig(env=Class), loop.resume(directory, env=Class)), or move it to a "
                     "module")
  try:
    obj = importlib.import_module(module_name)
  except ImportError as error:
    raise ValueError(f"cannot import the task {spec!r}: {error} (the module must be importable "
                     "from the current directory or sys.path)") from None
  for part in qualname.split("."):
    if not hasattr(obj, part):
      raise ValueError(f"cannot import the task {spec!r}: module {module_name!r} has no "
                       f"{qualname!r}")
    obj = getattr(obj, part)
  _check_class(obj, repr(spec))
  return obj


def task_id(cls: type[LocomotionEnv]) -> str:
  """The task's registered name, else `module:Qualname`."""
  for name, registered in _REGISTRY.items():
    if registered is cls:
      return name
  return f"{cls.__module__}:{cls.__qualname__}"


def robot_of(cls: type[LocomotionEnv]) -> str:
  """The robot a task is, or subclasses: the nearest class of its own model (`xml_file`) by its
  registered name ('Hopper' for a Hopper high jump), or by its class name where it is a robot
  of one's own that is not registered."""
  for base in cls.__mro__:
    if "xml_file" in vars(base):
      return next((name for name, c in _REGISTRY.items() if c is base), base.__name__)
  raise ValueError(f"{cls.__name__} subclasses none of the robots {list(BUILT_IN)}")


def _parameters(cls) -> dict[str, inspect.Parameter]:
  """The keyword settings `cls(...)` takes, following `**kwargs` up its bases."""
  out: dict[str, inspect.Parameter] = {}
  for base in cls.__mro__:
    if "__init__" not in vars(base):
      continue
    params = list(inspect.signature(vars(base)["__init__"]).parameters.values())[1:]
    for p in params:
      if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name != "physics":
        out.setdefault(p.name, p)
    if not any(p.kind == p.VAR_KEYWORD for p in params) or base is LocomotionEnv:
      break
  return out


def _check_names(cls: type[LocomotionEnv], given: dict) -> dict[str, inspect.Parameter]:
  """`cls`'s constructor parameters; a ValueError naming them when `given` has another name."""
  params = _parameters(cls)
  unknown = sorted(set(given) - set(params))
  if unknown:
    raise ValueError(f"unknown setting(s) {unknown} of the task {cls.__name__}; its settings are "
                     f"{sorted(params)}")
  return params


def task_settings(cls: type[LocomotionEnv], given: dict | None = None) -> dict:
  """Every constructor setting of `cls`, defaults included, with `given` in place.

  A ValueError for an unknown or missing setting, a value not of its default's type, or one JSON
  cannot hold."""
  given = dict(given or {})
  params = _check_names(cls, given)
  out = {}
  for name, p in sorted(params.items()):
    if name in given:
      value = given[name]
      if isinstance(p.default, (bool, int, float, str)):
        try:
          value = convert(type(p.default), value)
        except TypeError:
          raise ValueError(f"the task {cls.__name__}'s setting {name} takes a value of type "
                           f"{type(p.default).__name__} (like its default, {p.default!r}), got "
                           f"{value!r}") from None
    elif p.default is not p.empty:
      value = p.default
    else:
      raise ValueError(f"the task {cls.__name__} needs its setting {name!r}")
    try:
      json.dumps(value)
    except TypeError:
      raise ValueError(f"the task {cls.__name__}'s setting {name}={value!r} is not a number, "
                       "string, bool or list of them, which a checkpoint's config records"
                       ) from None
    out[name] = value
  return out


def settings_of(env: LocomotionEnv) -> dict:
  """The constructor settings an env was built with, defaults included."""
  return task_settings(type(env), getattr(env, "_given_settings", {}))


def make(spec: Any, physics: str = "mjx", **settings) -> LocomotionEnv:
  """Builds the task `spec` (a name, a `module:Class` path, a class) with these settings,
  stepped by `physics` (LocomotionEnv's)."""
  cls = task_class(spec)
  _check_names(cls, settings)
  if physics == "mjx":  # the default: also a task whose constructor does not pass it on
    return cls(**settings)
  try:
    return cls(physics=physics, **settings)
  except TypeError as error:
    if "physics" not in str(error):
      raise
    raise ValueError(f"the task {cls.__name__} takes no physics setting: its __init__ must "
                     "pass **settings on to its robot's") from None


def check_task(env: LocomotionEnv) -> None:
  """A one-line ValueError unless the reward is a dict of scalar terms, finite at reset, and
  `is_done` a scalar; compiles nothing."""
  name = type(env).__name__
  try:
    state = jax.eval_shape(env.reset, jax.ShapeDtypeStruct((2,), jnp.uint32))
  except Exception as error:  # noqa: BLE001 - the user's reward or termination code
    first = (str(error).strip().splitlines() or [""])[0]
    raise ValueError(f"the task {name} fails at reset: {type(error).__name__}: {first}") from None
  bad = {k: v.shape for k, v in state.metrics.items() if v.shape != ()}
  if bad:
    raise ValueError(f"the task {name}'s reward must return a dict of scalar terms; these are "
                     f"not scalars: {bad}")
  robot = state.info["robot"]
  done = jax.eval_shape(env.is_done, robot, state.metrics)
  if getattr(done, "shape", None) != ():
    raise ValueError(f"the task {name}'s is_done must return a scalar, got shape "
                     f"{getattr(done, 'shape', type(done).__name__)}")
  terms = jax.device_get(_reset_terms(env))
  nonfinite = {k: float(v) for k, v in terms.items() if not np.isfinite(v)}
  if nonfinite:
    raise ValueError(f"the task {name}'s reward is not finite at reset: {nonfinite}")


def _reset_terms(env: LocomotionEnv) -> dict:
  """The reward terms of a still step at the initial pose, on MuJoCo's C kinematics, as one
  compiled program."""
  data = mujoco.MjData(env.mj_model)
  mujoco.mj_kinematics(env.mj_model, data)

  def terms():
    robot = env.robot(data, jnp.zeros(len(env.feet)))
    return env.reward(robot, robot, jnp.zeros(env.action_size))
  return jax.jit(terms)()
