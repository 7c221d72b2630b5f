"""Tasks of one's own (Robolympics events) through the whole pipeline: naming them, training
them from the API and the CLI, sweeps, checkpoints that know their task, and bad input."""

import dataclasses
import json
import os
import sys

import events
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_hopper import envs
from mjx_hopper.core import train
from mjx_hopper.envs.events import AntLongJump, HighJump
from mjx_hopper.faces import cli, notebook
from mjx_hopper.run import checkpoints, loop, trainers
from mjx_hopper.settings.plan import resolve
from mjx_hopper.settings import presets
from configs import JUMP, TINY_ARGS


def test_a_task_is_named_by_class_instance_path_or_registered_name():
  for spec in (HighJump, HighJump(episode_steps=20), "mjx_hopper.envs.events:HighJump"):
    assert envs.task_class(spec) is HighJump
  assert envs.task_id(HighJump) == "mjx_hopper.envs.events:HighJump"
  assert envs.task_id(envs.Hopper) == "Hopper" and envs.robot_of(HighJump) == "Hopper"
  envs.register("HighJumpForTests", HighJump)
  try:
    assert envs.task_id(HighJump) == "HighJumpForTests"
    assert "HighJumpForTests" in envs.list_envs()
    assert isinstance(envs.make("HighJumpForTests"), HighJump)
  finally:
    del envs.tasks._REGISTRY["HighJumpForTests"]
  with pytest.raises(ValueError, match="'Hopper' is a built-in robot"):
    envs.register("Hopper", HighJump)


def test_settings_are_recorded_with_their_defaults():
  assert JUMP.task_id == "mjx_hopper.envs.events:HighJump"
  assert JUMP.task_settings() == {"height_weight": 10.0, "episode_steps": 30}
  # An instance's own settings count as given; the fields stay as they were given.
  cfg = loop.RunConfig(env=HighJump(height_weight=2, episode_steps=300))
  assert cfg.task_settings() == {"height_weight": 2.0, "episode_steps": 300}
  assert (cfg.env_settings, cfg.episode_steps) == ({}, None)
  saved = cfg.to_json()
  assert (saved["env_settings"], saved["episode_steps"]) == ({"height_weight": 2.0}, 300)
  assert loop.RunConfig(env="Ant").task_settings() == {"episode_steps": 1000}
  back = loop.RunConfig.from_json(json.loads(json.dumps(JUMP.to_json())))
  assert (back.env, back.env_settings, back.episode_steps) == (
      "mjx_hopper.envs.events:HighJump", {"height_weight": 10.0}, 30)


@pytest.mark.parametrize("robot", ["Hopper", "Walker2D", "HalfCheetah", "Ant", "Humanoid"])
def test_an_event_on_every_robot_gets_its_robots_preset(robot):
  class Event(getattr(envs, robot)):
    def reward(self, before, after, action):
      return {**super().reward(before, after, action), "up": after.body_xyz[2]}

  for kind in ("cpu", "gpu"):
    cfg = presets.agent_run_config(Event, kind, "d4pg")
    assert cfg.train == presets.get(robot, kind).train
    assert cfg.task_id.endswith("Event") and cfg.make_env().episode_steps == 1000
  env = cfg.make_env()
  envs.check_task(env)
  state = jax.eval_shape(env.step, jax.eval_shape(env.reset, jax.random.PRNGKey(0)),
                         jnp.zeros(env.action_size))
  assert "up" in state.metrics and state.reward.shape == ()


@pytest.mark.parametrize("env, settings, message", [
    ("events:Nope", {}, "cannot import the task 'events:Nope': module 'events' has no 'Nope'"),
    ("no_such_module:Jump", {}, "cannot import the task 'no_such_module:Jump': No module named"),
    ("events:NotAnEnv", {}, "'events:NotAnEnv' is not a LocomotionEnv subclass"),
    (HighJump, {"height": 1.0},
     r"unknown setting\(s\) \['height'\] of the task HighJump; its settings are "
     r"\['episode_steps', 'height_weight'\]"),
    (HighJump, {"height_weight": "tall"},
     "the task HighJump's setting height_weight takes a value of type float .*, got 'tall'"),
    ("__main__:Jump", {}, "defined in a notebook or a script .* pass the class itself again"),
])
def test_bad_tasks_are_refused_by_the_config(env, settings, message):
  with pytest.raises(ValueError, match=message):
    loop.RunConfig(env=env, env_settings=settings)


@pytest.mark.parametrize("task, message", [
    (events.Vector, r"the task Vector's reward must return a dict of scalar terms; these are not "
                    r"scalars: \{'xyz': \(3,\)\}"),
    (events.NaNAtReset, r"the task NaNAtReset's reward is not finite at reset: \{'log': nan\}"),
])
def test_bad_rewards_are_refused_before_any_compile(task, message, monkeypatch):
  def no_compile(*args, **kwargs):
    raise AssertionError("the trainer was built")
  monkeypatch.setattr(train, "make_trainer", no_compile)
  with pytest.raises(ValueError, match=message):
    trainers.build(resolve(dataclasses.replace(JUMP, env=task, env_settings={})))


def test_a_reward_that_turns_nan_mid_episode_ends_the_episode():
  env = events.LateNaN(episode_steps=50)
  push = jnp.array([1.0, -1.0, 1.0])

  @jax.jit
  def run(key):
    def one(state, _):
      nxt = env.step(state, push)
      return nxt, (nxt.done, nxt.reward, jnp.isfinite(nxt.obs).all())
    return jax.lax.scan(one, env.reset(key), None, length=20)[1]

  done, reward, finite_obs = jax.device_get(run(jax.random.PRNGKey(0)))
  end = int(np.argmax(done))
  assert done[end] == 1 and end < 19          # the episode ended when the reward went NaN
  assert np.isfinite(reward).all() and reward[end] == 0 and finite_obs.all()


@pytest.fixture(scope="module")
def jump_run(tmp_path_factory):
  """The tiny high jump trained from the API: (its directory, the Result)."""
  out = tmp_path_factory.mktemp("jump")
  return out, loop.run(dataclasses.replace(JUMP, out_dir=str(out)), progress=False)


def test_a_checkpoint_records_its_task_and_resume_finds_it(jump_run, capsys):
  out, result = jump_run
  saved = json.loads((out / "config.json").read_text())
  assert (saved["env"], saved["env_settings"], saved["episode_steps"]) == (
      "mjx_hopper.envs.events:HighJump", {"height_weight": 10.0}, 30)
  assert isinstance(result.trainer.env, HighJump)
  assert "height" in result.evaluation and "progress" not in result.evaluation
  resumed = loop.resume(str(out / "checkpoints"), progress=False, total_env_steps=120)
  assert train.iterations(resumed.state) == 15
  assert resumed.trainer.env.height_weight == 10.0


def _files(folder):
  return {p: os.path.getmtime(os.path.join(r, p)) for r, _, names in os.walk(folder)
          for p in names}


def test_another_task_or_setting_is_refused_and_nothing_changes(jump_run):
  out, _ = jump_run
  before = _files(out)
  ckpt = str(out / "checkpoints")
  with pytest.raises(ValueError, match=r"the task mjx_hopper.envs.events:HighJump "
                                       r"\(episode_steps=30, height_weight=10.0\), not Hopper$"):
    loop.resume(ckpt, env="Hopper")
  with pytest.raises(ValueError, match=r"env_settings: saved \{'height_weight': 10.0\}, now "
                                       r"\{'height_weight': 6.0\}"):
    loop.run(dataclasses.replace(JUMP, out_dir=str(out), env_settings={"height_weight": 6.0}),
             progress=False)
  with pytest.raises(ValueError, match=r"not mjx_hopper.envs.events:HighJump "
                                       r"\(episode_steps=30, height_weight=3.0\)"):
    checkpoints.load_policy(ckpt, env=HighJump(height_weight=3.0, episode_steps=30))
  assert _files(out) == before


def test_a_notebook_class_is_passed_again_in_a_new_process(jump_run, tmp_path, monkeypatch):
  """A class defined in a notebook (module __main__) cannot be imported by another process:
  there resuming asks for it, and takes it when passed again."""
  out, _ = jump_run

  class NotebookJump(HighJump):
    pass
  NotebookJump.__module__, NotebookJump.__qualname__ = "__main__", "NotebookJump"
  cfg = dataclasses.replace(JUMP, env=NotebookJump, out_dir=str(tmp_path))
  assert cfg.task_id == "__main__:NotebookJump"
  loop.run(cfg, progress=False)
  monkeypatch.delitem(envs.tasks._SEEN, "__main__:NotebookJump")  # as in a new process
  with pytest.raises(ValueError, match="cannot import; pass the class itself again"):
    loop.resume(str(tmp_path / "checkpoints"))
  monkeypatch.setattr(sys.modules["__main__"], "NotebookJump", NotebookJump, raising=False)
  _, agent_state, trainer = checkpoints.load_policy(str(tmp_path / "checkpoints"))  # a notebook ran
  assert type(trainer.env) is NotebookJump                                   # its cell again
  monkeypatch.delattr(sys.modules["__main__"], "NotebookJump")
  monkeypatch.delitem(envs.tasks._SEEN, "__main__:NotebookJump")
  _, _, trainer = checkpoints.load_policy(str(tmp_path / "checkpoints"), env=NotebookJump)
  assert type(trainer.env) is NotebookJump


@pytest.mark.slow
def test_the_cli_trains_evaluates_and_records_a_task_by_path(tmp_path, capsys):
  args = [a for a in TINY_ARGS if a != "Hopper"]
  args[args.index("--env")] = "--env=mjx_hopper.envs.events:HighJump"
  # JUMP on the command line: its trainer is reused.
  cli.main([*args, "--env-set", "height_weight=10.0",
            "--total-env-steps", "80", "--out-dir", str(tmp_path)])
  saved = json.loads((tmp_path / "config.json").read_text())
  assert (saved["env"], saved["env_settings"]) == ("mjx_hopper.envs.events:HighJump",
                                                    {"height_weight": 10.0})
  video = tmp_path / "jump.mp4"
  cli.main(["--cpu-devices", "2", "eval", "--checkpoint", str(tmp_path / "checkpoints"),
            "--episodes", "2", "--video", str(video)])
  assert "mjx_hopper.envs.events:HighJump / d4pg: return" in capsys.readouterr().out
  assert video.stat().st_size
  with pytest.raises(SystemExit, match="mjx-hopper train: the task HighJump's setting "
                                       "height_weight takes a value of type float"):
    cli.main([*args, "--env-set", "height_weight=tall", "--out-dir", str(tmp_path / "bad")])


@pytest.mark.parametrize("command, value, message", [
    ("train", "learning_rate=abc", "mjx-hopper train: learning_rate takes a float, got 'abc'"),
    ("sweep", "learning_rate=", "mjx-hopper sweep: learning_rate takes a float, got ''"),
    ("train", "policy_layers=(16,'x')", r"policy_layers takes a tuple of int, got \(16, 'x'\)"),
    ("sweep", "replay_ratio=x", "mjx-hopper sweep: replay_ratio takes a float, got 'x'"),
    ("train", "sigma_min=big", "sigma_min takes a float or None, got 'big'"),
])
def test_a_set_value_of_the_wrong_type_is_a_one_line_error(command, value, message, tmp_path):
  with pytest.raises(SystemExit, match=message):
    cli.main(["--cpu-devices", "2", command, "--set", value, "--out-dir", str(tmp_path)])
  assert not (tmp_path / "checkpoints").exists()


# The notebook's Ant event and its Walker2D, as its short mode trains and evaluates them, one
# member each (a sweep of a task of one's own is the notebook's population of high jumps): the
# notebook's programs, which the compile cache shares between the two (this file runs before
# the notebook, in the same worker: conftest.GROUPS). Walker2D is a second robot of the
# package's own through the trainer, with its robot's cpu preset.
@pytest.mark.slow
@pytest.mark.parametrize("task, kind, term", [(AntLongJump, "gpu", "flight"),
                                              ("Walker2D", "cpu", "progress")])
def test_the_notebooks_ant_event_and_walker_train(task, kind, term, tmp_path):
  cfg = dataclasses.replace(notebook.tiny(presets.agent_run_config(task, kind, "d4pg")),
                            log_every=0.0, out_dir=str(tmp_path))
  result = loop.run(cfg, progress=False)
  assert type(result.trainer.env) is envs.task_class(task)
  evals = [row for row in result.history if row["kind"] == "eval"]
  assert [row["env_steps"] for row in evals] == [40, 80]
  assert np.isfinite([row["eval_return"] for row in evals]).all()
  assert term in result.evaluation
  # The notebook's recorded evaluation of it (a robot on a free joint, too).
  episodes = notebook.evaluate(result, num_episodes=5, print_fn=lambda _: None)
  assert episodes["rewards"].shape == (5, 30)
  assert episodes["qpos"].shape == (31, result.trainer.env.mj_model.nq)
  np.testing.assert_allclose(episodes["rewards"].sum(1), episodes["return"], rtol=1e-5, atol=1e-4)
