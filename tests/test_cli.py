"""The command line is made from the config's fields: every run flag has its field's type, help
and (as --help shows) the value a run will use; only flags given replace the preset's."""

import argparse
import dataclasses
import json

import pytest

from mjx_hopper.settings.training import TrainConfig
from mjx_hopper.faces import cli
from mjx_hopper.run import loop
from mjx_hopper.settings import flags, presets
from mjx_hopper.settings.config import RunConfig


def parse(*argv):
  return cli.build_parser().parse_args(["train", *argv])


def test_every_run_flag_comes_from_a_field():
  base = presets.agent_run_config("Humanoid", "gpu", "d4pg")
  parser = cli.build_parser({"train": base, "sweep": base})
  train = parser.parse_args(["train"]).parser
  actions = {a.option_strings[0]: a for a in train._actions if a.option_strings}
  fields = flags.fields()
  assert {f.name for _, f in fields} == (
      {f.name for f in dataclasses.fields(RunConfig) if f.metadata["flag"]}
      | {f.name for f in dataclasses.fields(TrainConfig)})
  for owner, field in fields:
    action = actions[flags.flag_name(field)]
    assert action.dest == field.name
    assert action.help.startswith(field.metadata["help"])
    value = getattr(base if owner is RunConfig else base.train, field.name)
    assert action.help.endswith(f"(default: {value})"), field.name
    assert action.help.count("default") == 1, action.help  # a field's help states none
    assert action.type is {"int": int, "float": float}.get(str(field.type).split(" |")[0], str)
    assert action.default is argparse.SUPPRESS


def test_only_flags_given_replace_the_preset_in_any_order():
  walker = presets.run_config("Walker2D", "gpu")
  one = flags.run_config(parse("--num-envs", "256", "--env", "Walker2D", "--preset", "gpu",
                              "--total-env-steps", "5000"))
  two = flags.run_config(parse("--preset", "gpu", "--total-env-steps", "5000", "--env",
                              "Walker2D", "--num-envs", "256"))
  assert one == two
  assert one.train == dataclasses.replace(walker.train, num_envs=256)
  assert one.total_env_steps == 5000 and one.eval_every == walker.eval_every


def test_a_saved_config_is_restated_and_flags_override_it(tmp_path):
  cfg = presets.run_config("Hopper", "cpu", total_env_steps=1234, out_dir="runs/a")
  path = tmp_path / "config.json"
  path.write_text(json.dumps({**cfg.to_json(), "member_indices": [0]}))
  again = flags.run_config(parse("--config", str(path)))
  assert again.to_json() == cfg.to_json()
  moved = flags.run_config(parse("--out-dir", "runs/b", "--config", str(path), "--seed", "3"))
  assert (moved.out_dir, moved.seed, moved.total_env_steps) == ("runs/b", 3, 1234)


@pytest.mark.parametrize("content, message", [
    ({"hello": 1}, "is not a run's config.json"),
    ("[1, 2", "cannot read it as JSON"),
])
def test_a_bad_config_file_is_refused_in_one_line(tmp_path, content, message):
  path = tmp_path / "bad.json"
  path.write_text(content if isinstance(content, str) else json.dumps(content))
  with pytest.raises(ValueError, match=message):
    flags.run_config(parse("--config", str(path)))


def test_a_config_with_an_unknown_setting_or_a_sweep_is_refused(tmp_path):
  cfg = presets.run_config("Hopper", "cpu")
  path = tmp_path / "config.json"
  path.write_text(json.dumps({**cfg.to_json(), "learning_rat": 1}))
  with pytest.raises(ValueError, match=r"settings it does not know: learning_rat;"):
    flags.run_config(parse("--config", str(path)))
  path.write_text(json.dumps(dataclasses.replace(cfg, seeds=(0, 1)).to_json()))
  with pytest.raises(ValueError, match="is a sweep's config: run it with mjx-hopper sweep"):
    flags.run_config(parse("--config", str(path)))
  sweep = flags.run_config(cli.build_parser().parse_args(["sweep", "--config", str(path)]),
                          "sweep")
  assert sweep.seeds == (0, 1)


@pytest.mark.parametrize("argv", [["train", "--env", "Humanoid", "--preset", "gpu", "--help"],
                                  ["train", "-h", "--preset", "gpu", "--env", "Humanoid"]])
def test_help_shows_the_presets_values_wherever_it_is_asked(capsys, argv):
  cli.main(argv)
  text = " ".join(capsys.readouterr().out.split())
  assert "transitions per update (default: 8192)" in text
  assert "(default: Humanoid)" in text
  assert "usage: mjx-hopper train" in text
  episode_steps = text[text.index("--episode-steps EPISODE_STEPS "):].split(" --")[0]
  assert episode_steps.count("default") == 1, episode_steps


def test_each_command_is_a_function_registered_once():
  parser = cli.build_parser()
  argv = {"train": [], "sweep": [], "settings": [], "demo": [], "plot": ["runs/a"],
          "extract": ["--checkpoint", "c", "--member", "best", "--out", "o"],
          "eval": ["--checkpoint", "c", "--member", "best"],
          "export": ["--checkpoint", "c", "--out", "p.npz"]}
  assert set(argv) == set(cli.COMMANDS)
  for name, rest in argv.items():
    args = parser.parse_args([name, *rest])
    assert args.func is cli.COMMANDS[name][0] and args.command == name
  # `best` means the member of the best evaluation wherever a member is taken.
  assert {parser.parse_args([name, *rest]).member for name, rest in argv.items()
          if name in ("extract", "eval")} == {"best"}


@pytest.mark.parametrize("argv", [["--cpu-devices", "3", "settings"], ["settings", "--cpu-devices",
                                                                      "3"]])
def test_global_flags_go_before_or_after_the_command(argv):
  assert cli.build_parser().parse_args(argv).cpu_devices == 3


def test_the_global_flag_defaults_to_one_device_per_core():
  import os
  assert cli.build_parser().parse_args(["settings"]).cpu_devices == (os.cpu_count() or 1)


@pytest.mark.parametrize("argv, line", [
    (["extract", "--checkpoint", "nowhere", "--member", "best", "--out", "o"],
     "mjx-hopper extract: no checkpoint directory 'nowhere'"),
    (["eval", "--checkpoint", "nowhere"], "mjx-hopper eval: no checkpoint directory 'nowhere'"),
    (["settings", "--agent", "d5pg"], "mjx-hopper settings: unknown agent 'd5pg'"),
    (["train", "--set", "sigma"], "mjx-hopper train: --set takes name=value, got 'sigma'"),
    (["sweep", "--seeds", "0"], "mjx-hopper sweep: --seeds must be >= 1, got 0"),
    (["demo", "--steps", "0"], "mjx-hopper demo: --num-envs and --steps must be >= 1"),
    (["settings", "--cpu-devices", "0"], "mjx-hopper settings: --cpu-devices must be >= 1, got 0"),
    (["plot", "nowhere"], "mjx-hopper plot: nowhere holds no log.csv"),
    (["eval", "--pretrained", "Cheetah"], "mjx-hopper eval: no pretrained policy for 'Cheetah'"),
])
def test_a_users_error_is_one_line_naming_the_command(argv, line):
  with pytest.raises(SystemExit) as stop:
    cli.main(argv)
  message = str(stop.value.code)
  assert message.startswith(line) and "\n" not in message, message


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
  monkeypatch.setattr(loop, "run", lambda cfg, **kwargs: runs.append(cfg))
  cli.main(["--cpu-devices", "2", "train", "--config", str(path)])
  assert (runs[0].task_id, runs[0].total_env_steps) == ("Walker2D", 1234)
