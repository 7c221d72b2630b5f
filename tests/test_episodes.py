"""Episode statistics under random and zero actions, against PyBullet's own envs (their
episodes as tests/record_oracle.py recorded them in tests/oracle/); and a video of one (here, so
that it reuses this file's compiled episodes in the same test worker).

The contact models differ (Bullet's hard contacts, MuJoCo's soft ones), so episodes agree in
distribution, not step for step. A mean passes when |ours - bullet| <= max(rel * |bullet|, abs)
+ 3 standard errors of the difference: the first part is the agreement that docs/fidelity.md's
table shows, the second the sampling noise of the few episodes run here.
"""

import numpy as np
import pytest

from conftest import ROBOTS, make_env, mjx_episodes, oracle
from mjx_hopper.envs import base, render

pytestmark = pytest.mark.slow

TOLERANCE = {  # statistic: (relative, absolute)
    "length": (0.25, 1.0),
    "return": (0.15, 2.0),
    "alive": (0.0, 0.05),
    "progress": (0.0, 0.2),
    "electricity_cost": (0.15, 0.02),
    "joints_at_limit_cost": (0.0, 0.05),
    "feet_collision_cost": (0.0, 1e-9),
}
# Where a robot agrees less well (docs/fidelity.md says why): MuJoCo's joints move faster under
# random torques (electricity cost) and stop at their limits less often.
LOOSER = {
    ("HalfCheetah", "random"): {"return": (0.3, 2.0), "alive": (0.0, 0.3),
                                "electricity_cost": (0.4, 0.02),
                                "joints_at_limit_cost": (0.0, 0.08)},
    ("Ant", "random"): {"length": (0.3, 1.0), "return": (0.3, 2.0),
                        "electricity_cost": (0.35, 0.02)},
    ("Humanoid", "random"): {"return": (0.3, 2.0), "joints_at_limit_cost": (0.0, 0.16)},
    ("Humanoid", "zero"): {"length": (0.3, 1.0), "return": (0.3, 2.0),
                           "joints_at_limit_cost": (0.0, 0.08)},
}
# PyBullet's episodes per policy (HalfCheetah's and Ant's random ones are fewer and longer: see
# tests/record_oracle.py); the noise term widens with fewer.
BULLET_EPISODES = {"random": 30, "zero": 10}
FEWER_EPISODES = {("HalfCheetah", "random"): 10, ("Ant", "random"): 10}


@pytest.mark.parametrize("physics", base.PHYSICS)
@pytest.mark.parametrize("policy", ["random", "zero"])
@pytest.mark.parametrize("robot", ROBOTS)
def test_episode_statistics_match_bullet(robot, policy, physics):
  """In either physics engine: MuJoCo C's episodes agree with Bullet's as MJX's do."""
  episodes = FEWER_EPISODES.get((robot, policy), BULLET_EPISODES[policy])
  bullet = {name: oracle(robot)[f"{policy}_{name}"] for name in TOLERANCE}
  assert {len(v) for v in bullet.values()} == {episodes}
  ours = {k: v for k, v in mjx_episodes(robot, physics=physics)[policy].items() if k != "qpos"}
  assert set(ours) == set(TOLERANCE)
  tolerance = dict(TOLERANCE, **LOOSER.get((robot, policy), {}))
  for name, (rel, atol) in tolerance.items():
    b, m = bullet[name].mean(), ours[name].mean()
    noise = 3 * np.sqrt(bullet[name].var() / bullet[name].size + ours[name].var() / ours[name].size)
    assert abs(m - b) <= max(rel * abs(b), atol) + noise, (
        f"{robot} {policy} {name}: ours {m:.4f}, bullet {b:.4f}, allowed "
        f"{max(rel * abs(b), atol):.4f} + {noise:.4f}")


@pytest.mark.parametrize("robot", ROBOTS)
def test_return_is_sum_of_terms(robot):
  ours = mjx_episodes(robot)["random"]
  terms = sum(ours[k] for k in TOLERANCE if k not in ("length", "return"))
  np.testing.assert_allclose(ours["return"], terms * ours["length"], rtol=1e-4, atol=1e-2)


def test_half_cheetah_never_terminates_early():
  for policy in ("random", "zero"):
    assert (mjx_episodes("HalfCheetah")[policy]["length"] == 1000).all()


@pytest.mark.parametrize("robot", ROBOTS)
def test_random_episode_video(robot, tmp_path):
  import imageio_ffmpeg
  env = make_env(robot)
  episode = mjx_episodes(robot)["random"]
  length = min(int(episode["length"][0]), 150)
  frames = env.render(episode["qpos"][:length + 1], width=96, height=64)
  assert frames.shape == (length + 1, 64, 96, 3)
  assert np.abs(frames[0].astype(int) - frames[-1]).max() > 0  # the robot moved
  # Into a folder that does not exist yet, as `mjx-hopper eval`'s default runs/eval/ on a clone.
  path = render.write_mp4(str(tmp_path / "new" / "episode.mp4"), frames, fps=1 / env.dt)
  reader = imageio_ffmpeg.read_frames(path)
  meta = next(reader)
  assert tuple(meta["size"]) == (96, 64)
  assert sum(1 for _ in reader) == length + 1
  with pytest.raises(ValueError, match="frames must be uint8"):
    render.write_mp4(str(tmp_path / "bad.mp4"), frames.astype(float), fps=30)
