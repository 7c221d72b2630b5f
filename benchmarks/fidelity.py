"""Episode statistics of our envs against PyBullet's, under random and zero actions.

    python benchmarks/fidelity.py [--envs Hopper] [--episodes 256]

Prints, per statistic, PyBullet's mean ± std and ours, the table recorded in docs/fidelity.md.
"""

import time

import jax

import common
from mjx_hopper import envs
from mjx_hopper.core import rollout

pybullet_oracle = common.pybullet_oracle()


def main() -> None:
  parser = common.parser(__doc__)
  parser.add_argument("--envs", default="Hopper")
  parser.add_argument("--episodes", type=int, default=256, help="episodes per policy and engine")
  args = parser.parse_args()
  print(f"# fidelity, {time.strftime('%Y-%m-%d')}, {args.episodes} episodes per policy\n")
  print("| env | policy | statistic | PyBullet mean ± std | MJX mean ± std | MJX − PyBullet |")
  print("|---|---|---|---|---|---|")
  for env_id in args.envs.split(","):
    env = envs.make(env_id)
    bullet_env = pybullet_oracle.make(env_id)
    run = jax.jit(lambda key, scale: rollout.episodes(
        env, lambda obs, k: scale * rollout.random_policy(env.action_size)(obs, k), key,
        args.episodes))
    for policy, scale in (("random", 1.0), ("zero", 0.0)):
      ours = jax.device_get(run(jax.random.PRNGKey(1), scale))
      theirs = pybullet_oracle.run_episodes(bullet_env, args.episodes, policy, seed=0)
      for name in theirs:
        b, m = theirs[name], ours[name]
        print(f"| {env_id} | {policy} | {name} | {b.mean():.3f} ± {b.std():.3f} "
              f"| {m.mean():.3f} ± {m.std():.3f} | {m.mean() - b.mean():+.3f} |")


if __name__ == "__main__":
  main()
