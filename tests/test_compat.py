"""Every old name still works, warns with its replacement and the version that removes it, and
lives in mjx_hopper/compat.py alone."""

import importlib
import pathlib
import re
import sys

import pytest

import mjx_hopper
from mjx_hopper import agents, compat, config, loop, sweep

ROOT = pathlib.Path(__file__).resolve().parent.parent


def _version(text: str) -> tuple[int, ...]:
  return tuple(int(p) for p in text.split("."))


def _removals() -> list[str]:
  tables = (compat.KEYWORDS, compat.PRESETS, compat.FLAGS, compat.MODULES,
            *compat.NAMES.values())
  return [entry[-1] for table in tables for entry in table.values()]


def test_each_old_name_has_a_removal_version_after_this_one():
  removals = _removals()
  assert len(removals) == 2 + 1 + 5 + 2 + 7 + 8
  assert all(_version(r) > _version(mjx_hopper.__version__) for r in removals), removals


def test_the_changelog_states_the_policy():
  text = (ROOT / "CHANGELOG.md").read_text()
  assert "mjx_hopper/compat.py" in text and "DeprecationWarning" in text


def test_old_keywords_are_the_new_ones_and_warn():
  with pytest.warns(DeprecationWarning) as warned:
    old = config.RunConfig(preset="gpu", time_delta=3.0)
  assert old == config.RunConfig(agent_preset="gpu", log_every=3.0)
  assert sorted(str(w.message) for w in warned) == [
      "RunConfig(preset=...) is now RunConfig(agent_preset=...); the old name goes in "
      "mjx_hopper 0.5.0",
      "RunConfig(time_delta=...) is now RunConfig(log_every=...); the old name goes in "
      "mjx_hopper 0.5.0"]
  assert {w.filename for w in warned} == {__file__}


def test_an_old_preset_name_is_the_new_one_and_warns():
  with pytest.warns(DeprecationWarning, match="the preset 'seed' is now 'acme'"):
    assert agents.config("d4pg", "seed") == agents.config("d4pg", "acme")


def test_a_saved_config_with_old_names_is_read_silently(recwarn):
  cfg = config.RunConfig(agent_preset="acme", log_every=3.0, episode_steps=1000)
  saved = cfg.to_json()
  saved["preset"], saved["time_delta"] = "seed", saved.pop("log_every")
  del saved["agent_preset"]
  assert config.RunConfig.from_json(saved) == cfg
  assert not [w for w in recwarn if w.category is DeprecationWarning]


@pytest.mark.parametrize("module, name", [(m, n) for m, names in compat.NAMES.items()
                                          for n in names])
def test_a_moved_name_is_the_same_object_and_warns(module, name):
  home = importlib.import_module(compat.NAMES[module][name][0])
  short = module.removeprefix("mjx_hopper.")
  with pytest.warns(DeprecationWarning, match=rf"^{short}\.{name} is now "):
    assert getattr(importlib.import_module(module), name) is getattr(home, name)


def test_an_unknown_name_is_still_an_attribute_error():
  with pytest.raises(AttributeError, match="module 'mjx_hopper.loop' has no attribute 'resum'"):
    loop.resum  # noqa: B018
  assert not hasattr(sweep, "nothing")


@pytest.mark.parametrize("old", sorted(compat.MODULES))
def test_an_old_module_path_imports_the_module_it_moved_to(old, monkeypatch):
  new = importlib.import_module(compat.MODULES[old][0])
  monkeypatch.delitem(sys.modules, old, raising=False)
  with pytest.warns(DeprecationWarning, match=rf"{re.escape(old)} is now {re.escape(new.__name__)}"
                    ) as warned:
    exec(f"import {old} as imported", namespace := {})  # noqa: S102
  assert namespace["imported"] is new
  assert warned[0].filename == "<string>"  # the line that imports it, not importlib's
  assert new.__spec__.name == new.__name__  # the module itself is left as it was


def test_no_old_name_lives_outside_compat():
  """The stubs and re-export tails that held old names are gone."""
  assert not (ROOT / "mjx_hopper" / "networks.py").exists()
  assert not (ROOT / "mjx_hopper" / "distributional.py").exists()
  for path in (ROOT / "mjx_hopper").glob("*.py"):
    assert "noqa: F401" not in path.read_text(), path.name
