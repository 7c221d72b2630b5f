"""Every old name that still works, each with the version that removes it.

An old name warns (a DeprecationWarning in Python, a line on the command line) that names its
replacement, and is removed in the version given beside it (CHANGELOG.md states the policy).
Checkpoints and config.json files that hold old names are read as long as their checkpoint
format is.
"""

from __future__ import annotations

import functools
import importlib
import importlib.abc
import importlib.util
import sys
import warnings

# RunConfig's keywords: {old: (new, removed in)}.
KEYWORDS = {"preset": ("agent_preset", "0.5.0"), "time_delta": ("log_every", "0.5.0")}
# The agents' presets: {old: (new, removed in)}.
PRESETS = {"seed": ("acme", "0.5.0")}
# Flags of train and sweep: {old: (new, removed in)}; a new name of None: ignored.
FLAGS = {"--steps": ("--total-env-steps", "0.5.0"), "--out": ("--out-dir", "0.5.0"),
         "--tensorboard": ("--tensorboard-dir", "0.5.0"),
         "--chunk": ("--iterations-per-chunk", "0.5.0"), "--coordinator": (None, "0.5.0")}
# Modules: {old: (new, removed in)}.
MODULES = {"mjx_hopper.networks": ("mjx_hopper.agents.networks", "0.5.0"),
           "mjx_hopper.distributional": ("mjx_hopper.agents.distributional", "0.5.0")}
# Names of a module that live in another: {module: {name: (its module, removed in)}}.
NAMES = {
    "mjx_hopper.loop": {
        "build": ("mjx_hopper.runs", "0.5.0"), "init": ("mjx_hopper.runs", "0.5.0"),
        "restore": ("mjx_hopper.runs", "0.5.0"), "load_policy": ("mjx_hopper.runs", "0.5.0"),
        "extract": ("mjx_hopper.runs", "0.5.0"),
        "join_processes": ("mjx_hopper.parallel", "0.5.0"),
        "MAX_PENDING": ("mjx_hopper.evaluator", "0.5.0")},
    "mjx_hopper.sweep": {
        "PBT": ("mjx_hopper.pbt", "0.5.0"), "exploit_explore": ("mjx_hopper.pbt", "0.5.0"),
        "TRAINER_DYNAMIC": ("mjx_hopper.config", "0.5.0"),
        "check_grid": ("mjx_hopper.config", "0.5.0"),
        "check_value": ("mjx_hopper.config", "0.5.0"),
        "dynamic_settings": ("mjx_hopper.config", "0.5.0"),
        "members": ("mjx_hopper.config", "0.5.0"), "plot": ("mjx_hopper.curves", "0.5.0")},
}


def _warn(old: str, new: str, removed: str, stacklevel: int = 3) -> None:
  warnings.warn(f"{old} is now {new}; the old name goes in mjx_hopper {removed}",
                DeprecationWarning, stacklevel=stacklevel)


def moved(module: str, name: str):
  """`module`'s old name `name`, from the module it lives in now: a module's `__getattr__`."""
  if name not in NAMES.get(module, {}):
    raise AttributeError(f"module {module!r} has no attribute {name!r}")
  home, removed = NAMES[module][name]
  _warn(f"{module.removeprefix('mjx_hopper.')}.{name}",
        f"{home.removeprefix('mjx_hopper.')}.{name}", removed)
  return getattr(importlib.import_module(home), name)


def keywords(init):
  """RunConfig's constructor, taking the old keyword names too (`KEYWORDS`)."""
  @functools.wraps(init)
  def wrapped(self, *args, **kwargs):
    for old in KEYWORDS.keys() & kwargs.keys():
      new, removed = KEYWORDS[old]
      _warn(f"RunConfig({old}=...)", f"RunConfig({new}=...)", removed)
      kwargs[new] = kwargs.pop(old)
    return init(self, *args, **kwargs)
  return wrapped


def preset(name: str) -> str:
  """An agent preset's name now, for its old name or its own."""
  if name not in PRESETS:
    return name
  new, removed = PRESETS[name]
  _warn(f"the preset {name!r}", repr(new), removed, stacklevel=4)
  return new


def saved_config(saved: dict) -> dict:
  """A saved config (a checkpoint's or config.json) with its old names replaced, silently: a
  file cannot be told to change."""
  saved = {KEYWORDS[k][0] if k in KEYWORDS else k: v for k, v in saved.items()}
  if saved.get("agent_preset") in PRESETS:
    saved["agent_preset"] = PRESETS[saved["agent_preset"]][0]
  return saved


def flag(option: str, say) -> None:
  """Says (with `say`) that the command line's `option` is an old name, if it is one."""
  if option in FLAGS:
    new, removed = FLAGS[option]
    say(f"{option} is {'no longer needed' if new is None else f'now {new}'}; the old name "
        f"goes in mjx_hopper {removed}")


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
  """Imports an old module path (`MODULES`) as the module it moved to."""

  def find_spec(self, fullname, path, target=None):
    return importlib.util.spec_from_loader(fullname, self) if fullname in MODULES else None

  def create_module(self, spec):
    return None

  def exec_module(self, module):
    new, removed = MODULES[module.__name__]
    _warn(module.__name__, new, removed)  # (warnings skips importlib's frames)
    # The import system hands out what sys.modules holds under the name once this returns.
    sys.modules[module.__name__] = importlib.import_module(new)


def install_module_paths() -> None:
  """Lets the old module paths (`MODULES`) import, after every other finder has looked."""
  if not any(isinstance(f, _MovedModules) for f in sys.meta_path):
    sys.meta_path.append(_MovedModules())
