"""Episode statistics under random and zero actions, against PyBullet's HopperBulletEnv.

The contact models differ (Bullet's hard contacts and limits, MuJoCo's soft ones), so episodes
agree in distribution, not step for step. The tolerances are those recorded in docs/fidelity.md.
"""

import jax
import numpy as np
import pytest

from mjx_hopper import rollout
from mjx_hopper.envs import pybullet_oracle

TOLERANCE = {  # (relative, absolute): |ours - bullet| <= max(rel * |bullet|, abs)
    "length": (0.25, 1.0),
    "return": (0.1, 1.0),
    "alive": (0.0, 0.05),
    "progress": (0.0, 0.2),
    "electricity_cost": (0.1, 0.01),
    "joints_at_limit_cost": (0.0, 0.04),
    "feet_collision_cost": (0.0, 1e-9),
}


@pytest.fixture(scope="module")
def mjx_stats(hopper):
  """Both policies through one compiled program: `scale` 1 is random, 0 is zero actions."""

  @jax.jit
  def run(key, scale):
    random = rollout.random_policy(hopper.action_size)
    return rollout.episodes(hopper, lambda obs, k: scale * random(obs, k), key, 256)

  return {policy: jax.device_get(run(jax.random.PRNGKey(1), scale))
          for policy, scale in (("random", 1.0), ("zero", 0.0))}


@pytest.mark.parametrize("policy,episodes", [("random", 100), ("zero", 30)])
def test_episode_statistics_match_bullet(mjx_stats, policy, episodes):
  bullet = pybullet_oracle.run_episodes(pybullet_oracle.make("Hopper"), episodes, policy, seed=0)
  ours = mjx_stats[policy]
  assert set(ours) == set(TOLERANCE)
  for name, (rel, atol) in TOLERANCE.items():
    b, m = bullet[name].mean(), ours[name].mean()
    assert abs(m - b) <= max(rel * abs(b), atol), f"{policy} {name}: ours {m:.4f}, bullet {b:.4f}"
  assert (ours["length"] < 1000).all()  # every episode terminated by falling


def test_return_is_sum_of_terms(mjx_stats):
  ours = mjx_stats["random"]
  terms = sum(ours[k] for k in TOLERANCE if k not in ("length", "return"))
  np.testing.assert_allclose(ours["return"], terms * ours["length"], rtol=1e-4, atol=1e-3)
