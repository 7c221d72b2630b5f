"""Headless frames and videos, and the demo that the README runs."""

import numpy as np
import pytest

from conftest import ROBOTS, make_env, mjx_episodes
from mjx_hopper import cli
from mjx_hopper.envs import render


@pytest.mark.parametrize("robot", ROBOTS)
def test_one_frame(robot):
  env = make_env(robot)
  frame = env.render(env.mj_model.qpos0, width=160, height=120)
  assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
  assert frame.std() > 10  # not blank: a robot on a floor under a sky
  with pytest.raises(ValueError, match=rf"qpos must have shape \(nq,\) or \(T, nq\) with "
                                       rf"nq={env.mj_model.nq}"):
    env.render(np.zeros(5))


@pytest.mark.parametrize("robot", ROBOTS)
def test_random_episode_video(robot, tmp_path):
  import imageio_ffmpeg
  env = make_env(robot)
  episode = mjx_episodes(robot)["random"]
  length = min(int(episode["length"][0]), 150)
  frames = env.render(episode["qpos"][:length + 1], width=96, height=64)
  assert frames.shape == (length + 1, 64, 96, 3)
  assert np.abs(frames[0].astype(int) - frames[-1]).max() > 0  # the robot moved
  path = render.write_mp4(str(tmp_path / "episode.mp4"), frames, fps=1 / env.dt)
  reader = imageio_ffmpeg.read_frames(path)
  meta = next(reader)
  assert tuple(meta["size"]) == (96, 64)
  assert sum(1 for _ in reader) == length + 1
  with pytest.raises(ValueError, match="frames must be uint8"):
    render.write_mp4(str(tmp_path / "bad.mp4"), frames.astype(float), fps=30)


def test_demo_prints_throughput_and_writes_video(tmp_path, capsys):
  cli.demo(cli.build_parser().parse_args(
      ["demo", "--num-envs", "4", "--steps", "100", "--out", str(tmp_path)]))
  out = capsys.readouterr().out
  assert "env steps/s" in out and "compiled a 50-step chunk of 4 envs" in out
  assert (tmp_path / "hopper_random.mp4").stat().st_size > 1000


def test_cli_rejects_bad_arguments(capsys):
  with pytest.raises(SystemExit):
    cli.main(["demo", "--env", "Hoper"])
  assert ("unknown --env 'Hoper'; choose from ['Ant', 'HalfCheetah', 'Hopper', 'Humanoid', "
          "'Walker2D']") in capsys.readouterr().err
