"""The shipped policies (mjx_hopper/faces/pretrained/, made by benchmarks/pretrain.py): one per
robot, each under a megabyte, loaded by name with NumPy alone, recorded in benchmarks/results,
made for the robot as it is now, and scoring at or above the robot's score on the CPU."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from mjx_hopper import envs
from mjx_hopper.faces import export
from mjx_hopper.settings import presets

ROBOTS = envs.tasks.BUILT_IN
RESULTS = os.path.join(os.path.dirname(__file__), "..", "benchmarks", "results")
RETRAIN = "retrain it on a GPU: bash benchmarks/gpu.sh \"python benchmarks/pretrain.py {}\""


def shipped() -> list[str]:
  if not os.path.isdir(export.PRETRAINED):
    return []
  return sorted(f[:-4] for f in os.listdir(export.PRETRAINED) if f.endswith(".npz"))


def test_every_robot_ships_one_recorded_policy():
  assert shipped() == sorted(ROBOTS), (f"the shipped policies are {shipped()}; "
                                        + RETRAIN.format("ROBOT"))
  for robot in ROBOTS:
    assert os.path.getsize(export.pretrained_path(robot)) < 2**20, robot
    with open(os.path.join(RESULTS, f"pretrained_{robot}.json")) as f:
      record = json.load(f)["figures"]
    assert record["return"] >= presets.get(robot, "gpu").target, robot
    made = export.pretrained(robot).meta["pretrained"]
    assert (made["seed"], made["env_steps"]) == (record["seed"], record["env_steps"]), robot


def test_an_unknown_robot_is_one_line():
  with pytest.raises(ValueError, match=r"no pretrained policy for 'Cheetah'; the shipped ones "
                                       r"are \["):
    export.pretrained("Cheetah")


def test_a_shipped_policy_loads_with_numpy_alone(tmp_path):
  # A file of the shipped form in a folder of its own, so that this holds before any ships.
  meta = {"format": export.FORMAT, "agent": "d4pg", "compute_dtype": "float32",
          "observation_size": 3, "action_size": 2, "output": "tanh",
          "layers": [{"dtype": "float32", "norm": False, "activation": "none"}]}
  export.save(export.Policy({"w0": np.ones((3, 2), np.float32), "b0": np.zeros(2, np.float32)},
                            meta), str(tmp_path / "Walker.npz"))
  code = ("import sys\n"
          "from mjx_hopper.faces import export\n"
          f"export.PRETRAINED = {str(tmp_path)!r}\n"
          "print(export.pretrained('Walker')([0.1, 0.2, 0.3]).tolist())\n"
          "print(sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'flax')))")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
  assert out.stdout.splitlines() == [str(np.tanh(np.float32([0.6, 0.6])).tolist()), "[]"]


@pytest.mark.slow
@pytest.mark.parametrize("robot", ROBOTS)
def test_a_shipped_policy_fits_its_robot_and_scores(robot, tmp_path):
  path = export.pretrained_path(robot)
  recorded = export.pretrained(robot).meta.get("fingerprint")
  now = export.fingerprint(envs.make(robot))
  assert recorded == now, (f"{path} was trained on another {robot} (its model or observation "
                           f"changed: {recorded} then, {now} now); " + RETRAIN.format(robot))
  # 32 episodes, so that a fall shows in the mean at its rate, on any CPU: the Hopper falls
  # in about one in eight, whose chaotic episodes fall in other ones on another CPU (over 4, an
  # AMD host's mean was 2,081). A few frames: rendering on the CPU is slow.
  returns = export.evaluate_file(path, episodes=32, video_path=str(tmp_path / "a.mp4"),
                                 frame_every=100)["return"]
  assert os.path.getsize(tmp_path / "a.mp4") > 0
  assert returns.mean() >= presets.get(robot, "gpu").target, (
      f"{path} scores {returns.mean():.0f} on the CPU; " + RETRAIN.format(robot))


def test_a_film_of_no_frames_is_one_line():
  with pytest.raises(ValueError, match=r"^frame_every must be >= 1, got 0$"):
    export.evaluate_file(export.pretrained_path("Hopper"), video_path="x.mp4", frame_every=0)
