"""Headless frames and videos, and the demo that the README runs."""

import numpy as np
import pytest

from conftest import ROBOTS, make_env
from mjx_hopper.faces import cli


@pytest.mark.parametrize("robot", ROBOTS)
def test_one_frame(robot):
  env = make_env(robot)
  frame = env.render(env.mj_model.qpos0, width=160, height=120)
  assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
  assert frame.std() > 10  # not blank: a robot on a floor under a sky
  with pytest.raises(ValueError, match=rf"qpos must have shape \(nq,\) or \(T, nq\) with "
                                       rf"nq={env.mj_model.nq}"):
    env.render(np.zeros(5))


@pytest.mark.slow
def test_demo_prints_throughput_and_writes_video(tmp_path, capsys):
  cli.demo(cli.build_parser().parse_args(
      ["demo", "--num-envs", "4", "--steps", "100", "--out", str(tmp_path)]))
  out = capsys.readouterr().out
  assert "env steps/s" in out and "compiled a 50-step chunk of 4 envs" in out
  assert (tmp_path / "hopper_random.mp4").stat().st_size > 1000


def test_cli_rejects_bad_arguments():
  with pytest.raises(SystemExit, match=r"^mjx-hopper demo: unknown env 'Hoper'; valid envs are "
                                       r"\['Ant', 'HalfCheetah', 'Hopper', 'Humanoid', "
                                       r"'Walker2D'\]"):
    cli.main(["demo", "--env", "Hoper"])
