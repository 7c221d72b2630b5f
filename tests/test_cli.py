"""The command line is made from the config's fields: every run flag has its field's type, help
and (as --help shows) the value a run will use; only flags given replace the preset's."""

import argparse
import dataclasses
import json

import pytest

from mjx_hopper import cli, presets
from mjx_hopper.config import RunConfig
from mjx_hopper.train import TrainConfig


def parse(*argv):
  return cli.build_parser().parse_args(["train", *argv])


def test_every_run_flag_comes_from_a_field():
  base = presets.agent_run_config("Humanoid", "gpu", "d4pg")
  parser = cli.build_parser({"train": base, "sweep": base})
  commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
  actions = {a.dest: a for a in commands.choices["train"]._actions}
  flags = cli._run_flags()
  assert {f.name for _, f in flags} == (
      {f.name for f in dataclasses.fields(RunConfig) if f.metadata["flag"]}
      | {f.name for f in dataclasses.fields(TrainConfig)})
  for owner, field in flags:
    action = actions[field.name]
    assert cli.flag_name(field) in action.option_strings
    assert action.help.startswith(field.metadata["help"])
    value = getattr(base if owner is RunConfig else base.train, field.name)
    assert action.help.endswith(f"(default: {value})"), field.name
    assert action.type is {"int": int, "float": float}.get(str(field.type).split(" |")[0], str)
    assert action.default is argparse.SUPPRESS


def test_only_flags_given_replace_the_preset_in_any_order():
  walker = presets.run_config("Walker2D", "gpu")
  one = cli._run_config(parse("--num-envs", "256", "--env", "Walker2D", "--preset", "gpu",
                              "--steps", "5000"))
  two = cli._run_config(parse("--preset", "gpu", "--total-env-steps", "5000", "--env",
                              "Walker2D", "--num-envs", "256"))
  assert one == two
  assert one.train == dataclasses.replace(walker.train, num_envs=256)
  assert one.total_env_steps == 5000 and one.eval_every == walker.eval_every
  # Old flag names are aliases of the field's.
  old = cli._run_config(parse("--chunk", "7", "--out", "runs/x", "--log-every", "3"))
  assert (old.train.iterations_per_chunk, old.out_dir, old.log_every) == (7, "runs/x", 3.0)


def test_a_saved_config_is_restated_and_flags_override_it(tmp_path):
  cfg = presets.run_config("Hopper", "cpu", total_env_steps=1234, out_dir="runs/a")
  path = tmp_path / "config.json"
  path.write_text(json.dumps({**cfg.to_json(), "member_indices": [0]}))
  again = cli._run_config(parse("--config", str(path)))
  assert again.to_json() == cfg.to_json()
  moved = cli._run_config(parse("--out-dir", "runs/b", "--config", str(path), "--seed", "3"))
  assert (moved.out_dir, moved.seed, moved.total_env_steps) == ("runs/b", 3, 1234)


@pytest.mark.parametrize("content, message", [
    ({"hello": 1}, "is not a run's config.json"),
    ("[1, 2", "cannot read it as JSON"),
])
def test_a_bad_config_file_is_refused_in_one_line(tmp_path, content, message):
  path = tmp_path / "bad.json"
  path.write_text(content if isinstance(content, str) else json.dumps(content))
  with pytest.raises(ValueError, match=message):
    cli._run_config(parse("--config", str(path)))


def test_a_config_with_an_unknown_setting_or_a_sweep_is_refused(tmp_path):
  cfg = presets.run_config("Hopper", "cpu")
  path = tmp_path / "config.json"
  path.write_text(json.dumps({**cfg.to_json(), "learning_rat": 1}))
  with pytest.raises(ValueError, match=r"unknown settings \['learning_rat'\]"):
    cli._run_config(parse("--config", str(path)))
  path.write_text(json.dumps(dataclasses.replace(cfg, seeds=(0, 1)).to_json()))
  with pytest.raises(ValueError, match="is a sweep's config: run it with mjx-hopper sweep"):
    cli._run_config(parse("--config", str(path)))
  sweep = cli._run_config(cli.build_parser().parse_args(["sweep", "--config", str(path)]),
                          "sweep")
  assert sweep.seeds == (0, 1)


def test_help_shows_the_presets_values(capsys):
  with pytest.raises(SystemExit):
    cli.main(["train", "--env", "Humanoid", "--preset", "gpu", "--help"])
  text = " ".join(capsys.readouterr().out.split())
  assert "transitions per update (default: 8192)" in text
  assert "(default: Humanoid)" in text


def test_settings_lists_every_setting(capsys):
  cli.main(["settings", "--agent", "d4pg", "--env", "Hopper", "--preset", "gpu"])
  out = capsys.readouterr().out
  assert "--set learning_rate=" in out and "--batch-size" in out
  line = next(l for l in out.splitlines() if l.startswith("--set learning_rate="))
  assert line.split()[-1] == "yes" and "0.001" in line  # the preset's 1e-3, sweepable
  assert next(l for l in out.splitlines() if l.startswith("--batch-size")).split()[-1] == "no"


def test_the_command_line_restates_a_config_without_replacing_its_task(tmp_path, monkeypatch):
  cfg = presets.run_config("Walker2D", "cpu", total_env_steps=1234)
  path = tmp_path / "config.json"
  path.write_text(json.dumps(cfg.to_json()))
  runs = []
  monkeypatch.setattr(cli, "train", lambda args: runs.append(cli._run_config(args)))
  cli.main(["--cpu-devices", "2", "train", "--config", str(path)])
  assert (runs[0].task_id, runs[0].total_env_steps) == ("Walker2D", 1234)
