"""The per-robot presets, how the CLI starts from them, and stopping a run at a target return."""

import dataclasses
import json
import pathlib
import re
import sys
import warnings

import pytest

from mjx_hopper import agents, envs
from mjx_hopper.faces import cli, export
from mjx_hopper.run import loop, opening
from mjx_hopper.settings import flags, presets
from mjx_hopper.settings.training import TrainConfig
import configs
from configs import POPULATION  # four members of a tiny run: 4 envs, eval every 40 env steps

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "benchmarks"))
import report  # noqa: E402  (the results behind the README's table; files only)


def test_every_robot_has_a_valid_gpu_and_cpu_preset():
  for env in envs.list_envs():
    for kind in presets.KINDS:
      preset = presets.get(env, kind)
      preset.train.check(num_devices=1)
      agents.config(preset.agent, kind, **preset.agent_overrides)
      assert preset.why and preset.target > 0 and preset.minutes > 0
      cfg = presets.run_config(env, kind, max_minutes=1.0)
      assert (cfg.env, cfg.agent, cfg.train, cfg.max_minutes) == (env, preset.agent,
                                                                   preset.train, 1.0)
      assert cfg.total_env_steps == preset.env_steps
  # The 2-core CPU's Hopper preset is what the README's main job runs.
  assert presets.get("Hopper", "cpu").train == TrainConfig()


@pytest.mark.parametrize("kind, table", [("gpu", report.GPU), ("cpu", report.CPU)])
def test_each_preset_is_the_one_its_results_measured_with_the_budget_they_need(kind, table):
  # The README's table and the preset name one score, and the preset trains long enough to
  # reach it: 1.5 times its slowest seed's env steps and minutes (report.budget).
  for robot in report.ROBOTS:
    preset, names = presets.get(robot, kind), table[robot]
    for name in names:
      ran = report.load(name)["figures"]
      assert ran["target"] == preset.target, (robot, kind, name)
      assert [ran["agent"], ran["agent_overrides"], ran["train"]] == json.loads(json.dumps(
          (preset.agent, preset.agent_overrides, dataclasses.asdict(preset.train)))), name
    assert (preset.env_steps, preset.minutes) == report.budget(names), (robot, kind)
  # An event measured on its own task: its row in the table and its own preset agree too.
  for (task, task_kind), preset in presets.TASK_PRESETS.items():
    if task_kind == kind:
      names = table[f"{task.split(':')[-1]} (an event)"]
      ran = report.load(names[0])["figures"]
      assert (ran["robot"], ran["target"]) == (task, preset.target)
      assert [ran["agent"], ran["agent_overrides"], ran["train"]] == json.loads(json.dumps(
          (preset.agent, preset.agent_overrides, dataclasses.asdict(preset.train)))), names
      assert presets.get(task, kind) is preset
      assert (preset.env_steps, preset.minutes) == report.budget(names), (task, kind)


def test_the_notebooks_jump_trains_its_seed_for_the_budget_measured_on_it():
  # Its cell trains seed 0 with the event's settings; the results file timed that seed.
  notebook = json.loads((report.ROOT / "notebooks" / "robolympics.ipynb").read_text())
  cell = next("".join(c["source"]) for c in notebook["cells"]
              if "".join(c["source"]).startswith("jump_cfg = make_config("))
  ran = report.load(report.NOTEBOOK_JUMP)["figures"]
  preset = presets.get("mjx_hopper.envs.events:HighJump", "cpu")
  assert list(ran["seeds"]) == ["0"] and ran["target"] == preset.target
  assert ran["agent_overrides"] == json.loads(json.dumps(preset.agent_overrides))
  assert 'agent_overrides={"vmax": 900.0}' in cell and "stop_at_return=1500" in cell
  steps, minutes = report.budget([report.NOTEBOOK_JUMP])
  assert f"minutes={minutes:g}," in cell
  assert int(re.search(r"env_steps=([\d_]+)", cell).group(1)) >= steps


def test_the_budget_is_the_presets_unless_a_run_says_otherwise():
  hopper = presets.get("Hopper", "cpu")
  cfg = presets.run_config("Hopper", "cpu")
  assert (cfg.total_env_steps, cfg.max_minutes) == (hopper.env_steps, hopper.minutes)
  cfg = presets.run_config("Hopper", "cpu", total_env_steps=1000, max_minutes=None)
  assert (cfg.total_env_steps, cfg.max_minutes) == (1000, None)
  walker = presets.get("Walker2D", "gpu")
  cfg = run_config("--env", "Walker2D", "--preset", "gpu")
  assert (cfg.total_env_steps, cfg.max_minutes) == (walker.env_steps, walker.minutes)
  cfg = run_config("--env", "Walker2D", "--preset", "gpu", "--total-env-steps", "5000",
                   "--max-minutes", "0.5")
  assert (cfg.total_env_steps, cfg.max_minutes) == (5000, 0.5)
  # A step count given alone is the whole budget: the preset's minutes do not cut it short.
  cfg = presets.run_config("Hopper", "cpu", total_env_steps=1000)
  assert (cfg.total_env_steps, cfg.max_minutes) == (1000, None)
  cfg = run_config("--env", "Walker2D", "--preset", "gpu", "--total-env-steps", "5000")
  assert (cfg.total_env_steps, cfg.max_minutes) == (5000, None)
  sweep = flags.run_config(cli.build_parser().parse_args(["sweep", "--preset", "gpu"]), "sweep")
  assert sweep.total_env_steps == presets.get("Hopper", "gpu").env_steps


def test_other_agents_train_for_their_measured_budget_or_say_that_none_is_measured():
  for (robot, kind, agent), budget in presets.AGENT_BUDGETS.items():
    names = {"cpu": report.CPU, "gpu": report.GPU}[kind][f"{robot}, {agent.upper()}"]
    ran = report.load(names[0])["figures"]
    assert ran["target"] == presets.get(robot, kind).target
    assert [ran["agent"], ran["agent_overrides"]] == json.loads(json.dumps(
        [agent, presets.AGENT_OVERRIDES[robot, kind, agent]]))
    assert budget == report.budget(names), (robot, kind, agent)
    with warnings.catch_warnings():
      warnings.simplefilter("error")  # measured: nothing to say
      cfg = presets.agent_run_config(robot, kind, agent)
    assert (cfg.total_env_steps, cfg.max_minutes) == budget
    cfg = presets.agent_run_config(robot, kind, agent, max_minutes=1.0)
    assert (cfg.total_env_steps, cfg.max_minutes) == (budget[0], 1.0)
    assert presets.unmeasured_budget(robot, kind, agent) is None
  # From Python as from the CLI, a budget nobody measured is said, unless the run sets its own.
  with pytest.warns(UserWarning, match=r"no budget is measured for ddpg on Walker2D \(cpu\)"):
    cfg = presets.agent_run_config("Walker2D", "cpu", "ddpg")
  assert (cfg.total_env_steps, cfg.max_minutes) == (1_000_000, None)
  with pytest.warns(UserWarning, match="HighJump trains for its robot's budget"):
    presets.run_config(envs.events.HighJump, "gpu")
  with warnings.catch_warnings():
    warnings.simplefilter("error")
    presets.agent_run_config("Walker2D", "cpu", "ddpg", max_minutes=3.0)
    presets.run_config(envs.events.HighJump, "cpu")
  lines = {tuple(argv): flags.unmeasured_budget(cli.build_parser().parse_args(["train", *argv]))
           for argv in (["--agent", "ddpg"], ["--env", "Walker2D", "--agent", "ddpg"],
                        ["--env", "Walker2D", "--agent", "ddpg", "--max-minutes", "3"],
                        ["--env", "mjx_hopper.envs.events:HighJump"],
                        ["--env", "mjx_hopper.envs.events:HighJump", "--preset", "gpu"],
                        ["--agent-defaults", "acme"],
                        ["--preset", "gpu"])}
  assert lines == {
      ("--agent", "ddpg"): None, ("--env", "Walker2D", "--agent", "ddpg", "--max-minutes", "3"):
      None, ("--preset", "gpu"): None,
      ("--env", "Walker2D", "--agent", "ddpg"):
      "no budget is measured for ddpg on Walker2D (cpu): it trains 1,000,000 env steps, "
      "RunConfig's default, which may not reach a score; set --total-env-steps or --max-minutes",
      ("--env", "mjx_hopper.envs.events:HighJump"): None,  # measured on its own (TASK_PRESETS)
      ("--env", "mjx_hopper.envs.events:HighJump", "--preset", "gpu"):
      "mjx_hopper.envs.events:HighJump trains for its robot's budget (Hopper's gpu preset), "
      "measured on Hopper's own task; set --total-env-steps or --max-minutes to choose another",
      ("--agent-defaults", "acme"):
      "no budget is measured for the agent's acme defaults: it trains for the cpu preset's "
      "budget; set --total-env-steps or --max-minutes"}


def test_every_agents_robot_settings_are_valid():
  for (robot, kind, agent), overrides in presets.AGENT_OVERRIDES.items():
    assert presets.get(robot, kind).agent != agent  # the robot's preset would shadow them
    agents.config(agent, kind, **overrides)


def test_run_config_merges_agent_overrides():
  cfg = presets.run_config("Ant", "gpu", agent_overrides={"sigma": 0.2})
  assert cfg.agent_overrides == {**presets.get("Ant", "gpu").agent_overrides, "sigma": 0.2}
  layout = TrainConfig(replay_ratio=8.0)
  cfg = presets.run_config("Ant", "cpu", train=layout, seed=3)
  assert (cfg.train, cfg.seed, cfg.eval_every) == (layout, 3, presets.get("Ant", "cpu").eval_every)


@pytest.mark.parametrize("env, kind, message", [
    ("Hoper", "gpu", r"unknown env 'Hoper'; valid envs are \['Ant', "),
    ("Hopper", "tpu", r"unknown robot preset 'tpu'; valid presets are \['gpu', 'cpu'\]"),
])
def test_bad_preset_names(env, kind, message):
  with pytest.raises(ValueError, match=message):
    presets.get(env, kind)


def run_config(*argv):
  """The RunConfig that `mjx-hopper train ARGV` trains."""
  args = cli.build_parser().parse_args(["train", *argv])
  return flags.run_config(args)


def test_cli_starts_from_the_robot_preset():
  walker = presets.get("Walker2D", "gpu")
  cfg = run_config("--env", "Walker2D", "--preset", "gpu")
  assert (cfg.train, cfg.eval_every) == (walker.train, walker.eval_every)
  assert cfg.agent_overrides == walker.agent_overrides
  # A flag replaces its one setting and keeps the rest of the preset's.
  cfg = run_config("--env", "Walker2D", "--preset", "gpu", "--num-envs", "1024")
  assert cfg.train == dataclasses.replace(walker.train, num_envs=1024)
  # Another agent than the preset's gets its own defaults and the trainer's.
  cfg = run_config("--env", "Walker2D", "--preset", "gpu", "--agent", "ddpg")
  assert (cfg.agent, cfg.agent_defaults, cfg.train, cfg.agent_overrides) == (
      "ddpg", "gpu", TrainConfig(), {})
  # ... and the robot's own settings for that agent where it has them; --set wins.
  cfg = run_config("--env", "Hopper", "--agent", "ddpg", "--set", "sigma=0.3")
  assert (cfg.agent, cfg.agent_defaults, cfg.train) == ("ddpg", "cpu", TrainConfig())
  assert cfg.agent_overrides == {**presets.AGENT_OVERRIDES["Hopper", "cpu", "ddpg"], "sigma": 0.3}
  # D4PG's Hopper networks are 128-128 on the CPU; DDPG keeps its defaults' 256-256.
  d4pg = run_config("--env", "Hopper").agent_config()
  assert (d4pg.policy_layers, d4pg.critic_layers) == ((128, 128), (128, 128))
  assert cfg.agent_config().critic_layers == (256, 256)
  # The other robots' D4PG take the Hopper's cpu settings, but HalfCheetah's seeds stood still
  # with them, so it keeps D4PG's cpu defaults as they are.
  hopper = presets.get("Hopper", "cpu").agent_overrides
  for robot in ("Walker2D", "Ant", "Humanoid"):
    assert run_config("--env", robot).agent_overrides == hopper
  assert run_config("--env", "HalfCheetah").agent_overrides == {}
  dmpo = run_config("--env", "Hopper", "--agent", "dmpo")
  assert dmpo.agent_overrides == {"learning_rate": 1e-3, "policy_layers": (128, 128),
                                  "critic_layers": (128, 128)}
  assert dmpo.agent_config().critic_layers == (128, 128)
  assert run_config("--env", "Hopper", "--agent", "mpo").agent_overrides == {}
  # --agent-defaults acme: acme's values (the NMA notebook's), not the robot's over them; --set
  # still wins.
  acme = run_config("--env", "Hopper", "--agent-defaults", "acme", "--set", "sigma=0.25")
  assert (acme.agent_defaults, acme.agent_overrides) == ("acme", {"sigma": 0.25})
  assert acme.agent_config() == dataclasses.replace(agents.config("d4pg", "acme"), sigma=0.25)
  assert run_config("--env", "Hopper", "--agent-defaults", "cpu").agent_overrides == hopper
  # With no flags: the Hopper's cpu preset (the README's main job).
  cfg = run_config()
  assert (cfg.agent, cfg.agent_defaults, cfg.train, cfg.eval_every) == (
      "d4pg", "cpu", TrainConfig(), 200_000)


@pytest.mark.slow
def test_run_stops_once_every_member_reaches_the_target(tmp_path, capsys):
  cfg = dataclasses.replace(POPULATION, out_dir=str(tmp_path), stop_at_return=-1e9,
                            total_env_steps=10**6)
  result = loop.run(cfg, progress=False)
  # The first evaluation (at 40 env steps; training goes on while it compiles) stops the run.
  kinds = [r["kind"] for r in result.history]
  first = kinds.index("eval")
  assert int(result.history[first]["env_steps"]) == 40 and set(kinds[first:]) == {"eval"}
  env_steps = result.trainer.env_steps(result.state)
  assert (f"every member reached -1e+09 by the evaluation at 40 env steps: {env_steps:,} env "
          "steps") in capsys.readouterr().out


def test_the_gpu_preset_on_a_cpu_says_so():
  assert "bash scripts/setup.sh cuda" in opening.gpu_sizes_warning("gpu", "cpu")
  assert opening.gpu_sizes_warning("gpu", "gpu") is None
  assert opening.gpu_sizes_warning("cpu", "cpu") is None


class Stilts(envs.LocomotionEnv):
  """A robot of one's own: a model of its own (here the Hopper's file, with longer strides), its
  joints, feet and constants; its tasks, presets and flags need nothing more."""

  xml_file = envs.Hopper.xml_file
  joints, feet, power, initial_z = envs.Hopper.joints, envs.Hopper.feet, 1.5, 1.25
  power_coefs = envs.Hopper.power_coefs
  alive_bonus = envs.Hopper.alive_bonus


class StiltsJump(Stilts):
  """A task of that robot."""


def test_a_robot_of_ones_own_is_registered_in_one_place(monkeypatch):
  monkeypatch.setitem(envs.tasks._REGISTRY, "Stilts", Stilts)
  assert envs.robot_of(Stilts) == envs.robot_of(StiltsJump) == "Stilts"
  assert envs.robot_of(envs.events.HighJump) == "Hopper"
  for kind in presets.KINDS:  # no measured preset: D4PG's of the kind, RunConfig's budget
    assert presets.get("Stilts", kind) == presets.get(StiltsJump, kind) == presets.UNMEASURED[kind]
  cfg = run_config("--env", "Stilts", "--preset", "gpu")
  assert (cfg.task_id, cfg.agent, cfg.train, cfg.total_env_steps, cfg.max_minutes) == (
      "Stilts", "d4pg", presets.UNMEASURED["gpu"].train, 1_000_000, None)
  assert flags.unmeasured_budget(cli.build_parser().parse_args(["train", "--env", "Stilts"])) == (
      "no preset is measured for Stilts (cpu): it trains d4pg with its cpu settings for "
      "1,000,000 env steps, RunConfig's default, which may not reach a score; set "
      "--total-env-steps or --max-minutes")


class Twin(envs.LocomotionEnv):
  """A robot of one's own with the Hopper's model and constants, so that its programs are the
  Hopper's, which the suite has compiled (configs.TINY)."""

  xml_file, joints, feet = envs.Hopper.xml_file, envs.Hopper.joints, envs.Hopper.feet
  power, power_coefs, initial_z = envs.Hopper.power, envs.Hopper.power_coefs, envs.Hopper.initial_z
  alive_bonus = envs.Hopper.alive_bonus


def test_a_robot_of_ones_own_trains_evaluates_and_exports_from_the_cli(tmp_path, capsys):
  # Defined in this file and named as module:Class, with no preset of its own (D4PG's cpu
  # defaults); eval and export find it by the name its checkpoint saved.
  run = str(tmp_path / "run")
  args = configs.args_of(dataclasses.replace(configs.TINY, env=Twin))
  assert args[args.index("--env") + 1] == "test_presets:Twin"
  cli.main([*args, "--total-env-steps", "80", "--out-dir", run])
  cli.main(["--cpu-devices", "2", "eval", "--checkpoint", f"{run}/checkpoints", "--episodes", "2",
            "--video", f"{tmp_path}/v.mp4"])
  cli.main(["export", "--checkpoint", f"{run}/checkpoints", "--out", f"{tmp_path}/p.npz"])
  out = capsys.readouterr().out
  assert "test_presets:Twin / d4pg: return" in out and "over 2 episodes" in out, out
  policy = export.load(f"{tmp_path}/p.npz")
  assert (policy.observation_size, policy.action_size) == (15, 3)
  assert (tmp_path / "v.mp4").stat().st_size > 0
