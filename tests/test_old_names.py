"""0.x versions rename freely: an old name is refused, and a checkpoint or config.json saved
with one is refused in one line naming its format and the version that reads it."""

import importlib
import json
import pathlib

import pytest

import mjx_hopper
from mjx_hopper import agents, store
from mjx_hopper.faces import cli
from mjx_hopper.run import checkpoints
from mjx_hopper.settings import config
from checkpoint_worker import state

ROOT = pathlib.Path(__file__).resolve().parent.parent


def old_named(cfg: config.RunConfig) -> dict:
  """`cfg` saved as an older version named its settings."""
  saved = cfg.to_json()
  saved["preset"], saved["time_delta"] = saved.pop("agent_defaults"), saved.pop("log_every")
  return saved


def test_the_changelog_says_0x_versions_rename_freely():
  assert "0.x versions rename freely" in " ".join((ROOT / "CHANGELOG.md").read_text().split())


def test_old_names_in_python_and_on_the_command_line_are_refused():
  with pytest.raises(TypeError, match="preset"):
    config.RunConfig(preset="gpu")
  with pytest.raises(ValueError, match=r"unknown defaults 'seed' for d4pg; valid defaults are"):
    agents.config("d4pg", "seed")
  with pytest.raises(ModuleNotFoundError):
    importlib.import_module("mjx_hopper.networks")
  with pytest.raises(SystemExit):
    cli.build_parser().parse_args(["train", "--steps", "10"])


def test_a_config_json_with_old_names_is_refused_in_one_line(tmp_path):
  path = tmp_path / "config.json"
  path.write_text(json.dumps(old_named(config.RunConfig())))
  with pytest.raises(ValueError) as error:
    config.load(str(path))
  message = str(error.value)
  assert "\n" not in message
  assert message.startswith(f"--config {path}: the saved config (checkpoint format 1, saved by "
                            f"an older mjx_hopper) is not one mjx_hopper "
                            f"{mjx_hopper.__version__} reads: settings it does not know: "
                            "preset, time_delta;")


def test_an_old_defaults_value_is_refused_naming_the_format():
  saved = {**config.RunConfig().to_json(), "agent_defaults": "seed", "checkpoint_format": 1,
           "versions": {"mjx_hopper": "0.1.0"}}
  with pytest.raises(ValueError, match=r"^the saved config \(checkpoint format 1, saved by "
                     r"mjx_hopper 0\.1\.0\) is not one mjx_hopper .* reads: unknown defaults "
                     r"'seed'"):
    config.RunConfig.from_json(saved)


def test_a_config_saved_before_agent_defaults_had_its_name_loads():
  cfg = config.RunConfig(agent="ddpg", agent_defaults="acme", agent_overrides={"sigma": 0.25})
  saved = cfg.to_json()
  saved["agent_preset"] = saved.pop("agent_defaults")  # format 2, as 0.3.0 first saved it
  assert config.RunConfig.from_json(saved).to_json() == cfg.to_json()


def test_a_checkpoint_with_old_names_is_refused_and_kept(tmp_path):
  directory = tmp_path / "ckpt"
  mngr = store.manager(str(directory))
  store.save(mngr, state(1), old_named(config.RunConfig()))
  store.wait_and_record(mngr)
  files = store.manifests.files(str(directory))
  with pytest.raises(store.ConfigMismatch) as error:
    checkpoints.saved_config(str(directory), print_fn=lambda line: pytest.fail(f"printed {line!r}"))
  message = str(error.value)
  assert "\n" not in message
  assert message.startswith(f"{directory}: the saved config (checkpoint format "
                            f"{store.items.FORMAT}, saved by mjx_hopper "
                            f"{mjx_hopper.__version__}) is not one mjx_hopper")
  assert "settings it does not know: preset, time_delta" in message
  assert store.manifests.files(str(directory)) == files
