"""The `mjx-hopper` command line.

    mjx-hopper demo [--env Hopper] [--num-envs 1024] [--steps 500] [--out runs/demo]
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def _setup_jax(cpu_devices: int) -> None:
  """Splits the CPU into `cpu_devices` XLA devices and turns on the persistent compile cache.

  Must run before JAX initialises its backends.
  """
  if cpu_devices < 1:
    raise SystemExit(f"--cpu-devices must be >= 1, got {cpu_devices}")
  flag = f"--xla_force_host_platform_device_count={cpu_devices}"
  os.environ["XLA_FLAGS"] = " ".join(
      [f for f in os.environ.get("XLA_FLAGS", "").split()
       if not f.startswith("--xla_force_host_platform_device_count")] + [flag])
  import jax
  cache = os.environ.get("MJX_HOPPER_JAX_CACHE",
                         os.path.join(os.path.expanduser("~"), ".cache", "mjx_hopper", "jax"))
  jax.config.update("jax_compilation_cache_dir", cache)
  jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def demo(args: argparse.Namespace) -> None:
  """Batched random-action rollout: prints env steps/s, writes an mp4 of one episode."""
  import jax
  import numpy as np

  from mjx_hopper import envs, rollout
  from mjx_hopper.envs import render

  env = envs.make(args.env)
  print(f"{args.env}: observation {env.observation_size}, action {env.action_size}, "
        f"control dt {env.dt} s")
  print(f"devices: {jax.devices()}")
  chunk = 50
  init, run = rollout.make_stepper(env, args.num_envs, chunk)
  key = jax.random.PRNGKey(args.seed)
  state = init(key)
  t0 = time.perf_counter()
  run = run.lower(state, key).compile()
  print(f"compiled a {chunk}-step chunk of {args.num_envs} envs in "
        f"{time.perf_counter() - t0:.1f} s")
  n_chunks = max(1, args.steps // chunk)
  t0 = time.perf_counter()
  for i in range(n_chunks):
    state, reward = run(state, jax.random.fold_in(key, i))
    jax.block_until_ready(reward)
    steps = (i + 1) * chunk * args.num_envs
    rate = steps / (time.perf_counter() - t0)
    print(f"  {steps:>10,} env steps  {rate:>10,.0f} env steps/s  "
          f"mean reward {float(reward) / (chunk * args.num_envs):+.3f}", flush=True)
  stats = jax.jit(lambda k: rollout.episodes(
      env, rollout.random_policy(env.action_size), k, 1, record_qpos=True))(key)
  length = int(stats["length"][0])
  frames = render.render_frames(env.mj_model, np.asarray(stats["qpos"][:length + 1]))
  os.makedirs(args.out, exist_ok=True)
  path = render.write_mp4(os.path.join(args.out, f"{args.env.lower()}_random.mp4"), frames,
                          fps=1 / env.dt)
  print(f"random-action episode: {length} steps, return {float(stats['return'][0]):.1f}; "
        f"video: {path}")


def build_parser() -> argparse.ArgumentParser:
  parser = argparse.ArgumentParser(prog="mjx-hopper", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1,
                      help="XLA CPU devices to split the env batch over (default: all cores)")
  sub = parser.add_subparsers(dest="command", required=True)
  p = sub.add_parser("demo", help="batched random rollout, env steps/s, and a video")
  p.add_argument("--env", default="Hopper")
  p.add_argument("--num-envs", type=int, default=1024)
  p.add_argument("--steps", type=int, default=500, help="steps of every env")
  p.add_argument("--seed", type=int, default=0)
  p.add_argument("--out", default="runs/demo")
  return parser


def main(argv: list[str] | None = None) -> None:
  parser = build_parser()
  args = parser.parse_args(argv)
  _setup_jax(args.cpu_devices)
  if args.command == "demo":
    from mjx_hopper import envs
    if args.env not in envs.list_envs():
      parser.error(f"unknown --env {args.env!r}; choose from {envs.list_envs()}")
    if args.num_envs < 1 or args.steps < 1:
      parser.error("--num-envs and --steps must be >= 1")
    demo(args)


if __name__ == "__main__":
  main(sys.argv[1:])
