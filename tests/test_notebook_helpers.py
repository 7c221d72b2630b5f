"""The notebook's library pieces on a tiny run: `loop.resume`, the recorded evaluation (every
step's reward), inline videos, the seed's reward plot, the learning curve from log.csv, and
the tiny settings of the notebook's short mode."""

import base64
import json

import matplotlib
import numpy as np
import pytest

from mjx_hopper.faces import cli, notebook
from mjx_hopper.run import loop
from mjx_hopper.settings.plan import resolve
from mjx_hopper.settings import flags, presets

import configs

matplotlib.use("Agg")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
  """A tiny D4PG run of 80 env steps, the same resumed to 160 (with what it printed), and 5
  recorded episodes of its policy."""
  folder = tmp_path_factory.mktemp("run")
  cfg = notebook.tiny(loop.RunConfig(out_dir=str(folder)))
  first = loop.run(cfg, progress=False)
  printed = []
  resumed = loop.resume(str(folder / "checkpoints"), total_env_steps=160, progress=False,
                        print_fn=printed.append)
  episodes = notebook.evaluate(resumed, num_episodes=5, print_fn=printed.append)
  return cfg, first, resumed, "\n".join(printed), episodes


def test_resume_continues_the_saved_run_with_its_config(runs, tmp_path):
  cfg, first, resumed, printed, _ = runs
  printed_evaluation = printed.splitlines()[-1]
  step = int(first.state.iteration[0])
  assert f"resumed from {cfg.out_dir}/checkpoints, step {step}" in printed
  assert int(resumed.state.iteration[0]) == 2 * step
  # The best evaluation's record and agent come back with the checkpoint.
  assert resumed.best_return[0] >= first.best_return[0] > -np.inf
  assert "the policy of the best evaluation (return" in printed_evaluation
  with open(f"{cfg.out_dir}/config.json") as f:
    assert loop.RunConfig.from_json(json.load(f)).total_env_steps == 160
  with pytest.raises(ValueError, match="from another config .*seed"):
    loop.resume(f"{cfg.out_dir}/checkpoints", seed=1, progress=False)
  with pytest.raises(FileNotFoundError, match="no checkpoint directory"):
    loop.resume(str(tmp_path / "nothing"))


def test_recorded_rewards_sum_to_the_returns(runs):
  episodes = runs[-1]
  rewards, lengths = episodes["rewards"], episodes["length"]
  assert rewards.shape == (5, 30) and episodes["qpos"].shape == (31, 6)
  np.testing.assert_allclose(rewards.sum(1), episodes["return"], rtol=1e-5, atol=1e-4)
  after_end = np.arange(30)[None, :] >= lengths[:, None]
  assert (rewards[after_end] == 0).all() and (rewards[~after_end] != 0).all()


def test_video_and_episode_reward_plot(runs, tmp_path):
  _, _, resumed, _, episodes = runs
  shown = notebook.video(resumed.trainer.env, episodes, str(tmp_path / "policy.mp4"))
  assert "<video" in shown._repr_html_()
  assert (tmp_path / "policy.mp4").stat().st_size > 1000
  (tmp_path / "other.mp4").write_bytes(b"not really a video")
  pair = notebook.side_by_side({"trained <D4PG>": str(tmp_path / "policy.mp4"),
                                "random": str(tmp_path / "other.mp4")})._repr_html_()
  assert pair.count("<video") == 2 and "trained &lt;D4PG&gt;" in pair
  assert base64.b64encode(b"not really a video").decode() in pair
  lines = notebook.plot_episode_rewards(episodes).get_lines()
  assert len(lines) == 5
  assert lines[-1].get_xdata()[-1] == episodes["length"].sum() - 1  # one after another
  first = episodes["rewards"][0, :episodes["length"][0]]
  np.testing.assert_array_equal(lines[0].get_ydata(), first)


def test_learning_curve_reads_log_csv(runs):
  cfg = runs[0]
  log = notebook.read_log(f"{cfg.out_dir}/log.csv")
  np.testing.assert_array_equal(log["eval"]["env_steps"], [40, 80, 120, 160])
  assert np.isnan(log["train"]["eval_return"]).all()  # a train row leaves it empty
  curves = {line.get_label(): line for line in
            notebook.plot_learning_curve(f"{cfg.out_dir}/log.csv").get_lines()}
  evaluation = curves["evaluation (deterministic policy)"]
  np.testing.assert_array_equal(evaluation.get_ydata(), log["eval"]["eval_return"])


@pytest.mark.parametrize("agent", configs.AGENTS)
def test_tiny_is_the_tests_tiny_run(agent):
  """The notebook's short mode of a robot's preset trains what the suite's shared runs train,
  in Python and on the command line (tests/configs.py), so that they share compiled programs:
  everything that shapes the trainer is equal (the plan's `key`)."""
  cfg = notebook.tiny(presets.agent_run_config("Hopper", "cpu", agent, total_env_steps=5_000_000,
                                               max_minutes=5, out_dir="runs/x"))
  assert cfg.out_dir == "runs/x" and cfg.max_minutes is None and cfg.total_env_steps == 80
  args = cli.build_parser().parse_args([*configs.tiny_args(agent)[2:], "--total-env-steps", "80"])
  from_cli = flags.run_config(args)
  assert resolve(cfg).key == resolve(configs.tiny(agent)).key == resolve(from_cli).key
  assert from_cli.log_every == 0 and from_cli.eval_every == cfg.eval_every


def test_live_curve_draws_one_figure_in_place(capsys):
  curve = notebook.LiveCurve(every=0.0)
  curve(40, {"kind": "train", "episode_return": float("nan")})  # no episode ended yet
  curve(80, {"kind": "train", "episode_return": 12.0})
  curve(80, {"kind": "eval", "eval_return": 30.0})
  assert (curve.train, curve.eval) == ([(80, 12.0)], [(80, 30.0)])
  handle = curve.handle
  fig = curve.draw()
  assert curve.handle is handle  # the same output, updated
  assert [len(line.get_xdata()) for line in fig.axes[0].lines] == [1, 1]
