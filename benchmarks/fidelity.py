"""Episode statistics of our envs against PyBullet's, under random and zero actions: each
statistic's mean and std over the episodes, per robot, policy and engine. Needs PyBullet (the
oracle extra; its wheels are for Python 3.11). BENCHMARKS.md shows the table.

    python benchmarks/fidelity.py [--envs Hopper] [--episodes 256]
"""

import jax
import numpy as np

import common
from mjx_hopper import envs
from mjx_hopper.core import rollout

pybullet_oracle = common.pybullet_oracle()


def main() -> None:
  parser = common.parser(__doc__)
  parser.add_argument("--envs", default="Hopper")
  parser.add_argument("--episodes", type=int, default=256, help="episodes per policy and engine")
  args = parser.parse_args()
  rows = []
  for env_id in args.envs.split(","):
    env = envs.make(env_id)
    bullet_env = pybullet_oracle.make(env_id)
    run = jax.jit(lambda key, scale: rollout.episodes(
        env, lambda obs, k: scale * rollout.random_policy(env.action_size)(obs, k), key,
        args.episodes))
    for policy, scale in (("random", 1.0), ("zero", 0.0)):
      ours = jax.device_get(run(jax.random.PRNGKey(1), scale))
      theirs = pybullet_oracle.run_episodes(bullet_env, args.episodes, policy, seed=0)
      for engine, stats in (("PyBullet", theirs), ("MJX", ours)):
        summary = {name: [float(np.mean(stats[name])), float(np.std(stats[name]))]
                   for name in theirs}
        rows.append({"robot": env_id, "policy": policy, "engine": engine, **summary})
        print(f"{env_id}, {policy}, {engine}: " + ", ".join(
            f"{name} {mean:.3f} ± {std:.3f}" for name, (mean, std) in summary.items()))
  common.write_results("fidelity", {"episodes": args.episodes, "rows": rows})


if __name__ == "__main__":
  main()
