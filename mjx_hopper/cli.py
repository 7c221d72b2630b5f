"""The `mjx-hopper` command line.

    mjx-hopper train [--env Hopper] [--agent d4pg|ddpg|mpo|dmpo] [--preset cpu|gpu] [--out DIR]
    mjx-hopper train --env my_events:HighJump --env-set height_weight=5.0   # a task of your own
    mjx-hopper sweep --seeds 4 --set learning_rate=1e-4,3e-4 [train's flags]
    mjx-hopper extract --checkpoint DIR --member 3 --out DIR
    mjx-hopper eval --checkpoint DIR [--member 0] [--episodes 16] [--video out.mp4]
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
  import mjx_hopper
  os.environ["XLA_FLAGS"] = mjx_hopper.xla_flags_with_cpu_devices(cpu_devices)
  mjx_hopper.use_compile_cache()


def demo(args: argparse.Namespace) -> None:
  """Batched random-action rollout: prints env steps/s, writes an mp4 of one episode."""
  import jax
  import numpy as np

  from mjx_hopper import envs, rollout
  from mjx_hopper.envs import render

  env = envs.make(args.env)
  envs.check_task(env)
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


def _overrides(pairs: list[str], flag: str = "--set") -> dict:
  """--set name=value pairs as a dict; values are parsed as Python literals when they can be."""
  import ast
  out = {}
  for pair in pairs:
    name, sep, value = pair.partition("=")
    if not sep:
      raise SystemExit(f"{flag} takes name=value, got {pair!r}")
    try:
      out[name] = ast.literal_eval(value)
    except (ValueError, SyntaxError):
      out[name] = value
  return out


def _sweep_settings(pairs: list[str], agent: str, preset: str) -> tuple[dict, dict]:
  """(fixed settings, grid) of a sweep's --set pairs: a dynamic setting given several
  comma-separated values (name=v1,v2) is swept; any other is one value for every member."""
  from mjx_hopper import sweep
  try:
    dynamic = set(sweep.dynamic_settings(agent, preset))
  except ValueError as error:
    raise SystemExit(f"mjx-hopper sweep: {error}")
  fixed, grid = {}, {}
  for name, value in _overrides(pairs).items():
    if isinstance(value, tuple) and (name in dynamic or any(isinstance(v, tuple) for v in value)):
      grid[name] = value
    else:
      fixed[name] = value
  return fixed, grid


def _run_config(args: argparse.Namespace, agent_overrides: dict, **sweep):
  """The RunConfig of train's (and sweep's) flags: the robot's preset (`mjx_hopper.presets`)
  when it has one of this --preset for this agent, else the agent's preset with the trainer's
  defaults; then every flag given, and --set, replace its settings."""
  import dataclasses

  from mjx_hopper import presets
  base = presets.agent_run_config(args.env, args.preset, args.agent or "d4pg")
  env_settings = {**base.env_settings, **_overrides(args.env_set, "--env-set")}
  flags = dict(num_envs=args.num_envs, unroll_length=args.unroll_length,
               batch_size=args.batch_size, replay_ratio=args.replay_ratio,
               replay_size=args.replay_size, min_replay=args.min_replay,
               iterations_per_chunk=args.chunk)
  trainer = dataclasses.replace(base.train, **{k: v for k, v in flags.items() if v is not None})
  return dataclasses.replace(
      base, env_settings=env_settings,
      agent_overrides={**base.agent_overrides, **agent_overrides}, train=trainer,
      total_env_steps=args.steps, max_minutes=args.max_minutes,
      stop_at_return=args.stop_at_return, eval_every=args.eval_every or base.eval_every,
      eval_episodes=args.eval_episodes, eval_on=args.eval_on, episode_steps=args.episode_steps,
      seed=args.seed,
      out_dir=args.out, tensorboard_dir=args.tensorboard, time_delta=args.log_every,
      checkpoint_minutes=args.checkpoint_minutes, **sweep)


def train(args: argparse.Namespace) -> None:
  """Trains an agent, with progress, a CSV log, checkpoints and a final evaluation."""
  from mjx_hopper import loop
  try:
    cfg = _run_config(args, _overrides(args.set))
    loop.run(cfg, checkpoint_dir=args.checkpoint_dir, progress=not args.no_progress)
  except ValueError as error:
    raise SystemExit(f"mjx-hopper train: {error}")


def sweep(args: argparse.Namespace) -> None:
  """Trains a sweep's members at once: log.csv (a row per member per chunk and evaluation),
  curves.png, a ranking, checkpoints; under jax.distributed, each process its share."""
  from mjx_hopper import loop
  if args.seeds < 1:
    raise SystemExit(f"mjx-hopper sweep: --seeds must be >= 1, got {args.seeds}")
  process = None
  if args.distributed or args.coordinator or args.num_processes or args.process_id is not None:
    process = loop.join_processes(args.coordinator, args.num_processes, args.process_id)
  fixed, grid = _sweep_settings(args.set, args.agent or "d4pg", args.preset)
  replay_ratio = fixed.pop("replay_ratio", None)
  if replay_ratio is not None:
    args.replay_ratio = replay_ratio
  try:
    cfg = _run_config(args, fixed, seeds=tuple(range(args.seed, args.seed + args.seeds)),
                      grid=grid, pbt=_pbt(args))
    loop.run(cfg, checkpoint_dir=args.checkpoint_dir, progress=not args.no_progress,
             process=process)
  except ValueError as error:
    raise SystemExit(f"mjx-hopper sweep: {error}")


def _pbt(args: argparse.Namespace):
  """The sweep.PBT of sweep's --pbt flags (None without --pbt)."""
  from mjx_hopper import sweep
  given = [flag for flag, value in (("--pbt-every", args.pbt_every),
                                    ("--pbt-fraction", args.pbt_fraction),
                                    ("--pbt-bounds", args.pbt_bounds)) if value]
  if not args.pbt:
    if given:
      raise ValueError(f"{', '.join(given)} set(s) population-based training: add --pbt")
    return None
  settings = dict(every=args.pbt_every, fraction=args.pbt_fraction,
                  bounds=_overrides(args.pbt_bounds, "--pbt-bounds"))
  return sweep.PBT(**{k: v for k, v in settings.items() if v is not None})


def _member(text: str) -> int | str:
  """extract's --member: an index, or "best"."""
  if text == "best":
    return text
  try:
    return int(text)
  except ValueError:
    raise argparse.ArgumentTypeError(f"takes a member's index or 'best', got {text!r}") from None


def extract(args: argparse.Namespace) -> None:
  """Writes one member of a sweep's checkpoint as a single run's checkpoint."""
  from mjx_hopper import loop
  try:
    loop.extract(args.checkpoint, args.member, args.out)
  except (ValueError, FileNotFoundError) as error:
    raise SystemExit(f"mjx-hopper extract: {error}")


def evaluate(args: argparse.Namespace) -> None:
  """Loads the policy of a checkpoint, evaluates it and writes an mp4 of one episode."""
  import jax
  import numpy as np

  from mjx_hopper import loop, train as train_lib
  from mjx_hopper.envs import render
  try:
    cfg, agent_state, trainer = loop.load_policy(args.checkpoint, args.member,
                                                 which="latest" if args.latest else "best")
  except (ValueError, FileNotFoundError) as error:
    raise SystemExit(f"mjx-hopper eval: {error}")
  result = jax.device_get(jax.jit(
      lambda s, k: train_lib.evaluate(trainer.env, trainer.agent, s, k, args.episodes,
                                      record_qpos=True))(agent_state,
                                                         jax.random.PRNGKey(args.seed)))
  returns = np.asarray(result["return"])
  print(f"{cfg.env} / {cfg.agent}: return {returns.mean():.1f} +- {returns.std():.1f}, length "
        f"{np.mean(result['length']):.0f} over {args.episodes} episodes")
  length = int(result["length"][0])
  frames = render.render_frames(trainer.env.mj_model, np.asarray(result["qpos"][:length + 1]))
  path = render.write_mp4(args.video, frames, fps=1 / trainer.env.dt)
  print(f"video of episode 0 ({length} steps, return {returns[0]:.1f}): {path}")


def build_parser() -> argparse.ArgumentParser:
  parser = argparse.ArgumentParser(prog="mjx-hopper", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1,
                      help="XLA CPU devices to split the env batch over (default: all cores)")
  sub = parser.add_subparsers(dest="command", required=True)
  t = sub.add_parser("train", help="train an agent (progress, CSV log, checkpoints, evaluation)")
  _add_run_flags(t)
  w = sub.add_parser("sweep", help="train many seeds and settings at once, in one program")
  _add_run_flags(w, sweep=True)
  w.add_argument("--seeds", type=int, default=1, help="members per setting: seeds SEED, ...")
  w.add_argument("--distributed", action="store_true",
                 help="run under jax.distributed (each process trains its share of the members)")
  w.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                 help="jax.distributed: process 0's address (with --num-processes, "
                      "--process-id); each process trains its share of the members")
  w.add_argument("--num-processes", type=int, default=None)
  w.add_argument("--process-id", type=int, default=None)
  w.add_argument("--pbt", action="store_true",
                 help="population-based training: the worst members copy the best and "
                      "perturb the swept settings (docs/pbt.md)")
  w.add_argument("--pbt-every", type=int, default=None, metavar="N",
                 help="evaluations between PBT steps (default 2)")
  w.add_argument("--pbt-fraction", type=float, default=None, metavar="F",
                 help="the worst F of the members copy one of the best F (default 0.25)")
  w.add_argument("--pbt-bounds", action="append", default=[], metavar="NAME=LOW,HIGH",
                 help="bounds of a swept setting under PBT (default: the grid's smallest and "
                      "largest value)")
  x = sub.add_parser("extract", help="write one member of a sweep as a single run's checkpoint")
  x.add_argument("--checkpoint", required=True, help="the sweep's checkpoint directory")
  x.add_argument("--member", type=_member, required=True,
                 help="the member's index (log.csv), or best: the member of the best evaluation")
  x.add_argument("--out", required=True, help="folder for its checkpoints/ and config.json")
  e = sub.add_parser("eval", help="evaluate a checkpoint's policy and write an mp4")
  e.add_argument("--checkpoint", required=True, help="a checkpoint directory")
  e.add_argument("--member", type=int, default=0, help="which member of a sweep's checkpoint")
  e.add_argument("--latest", action="store_true",
                 help="the latest policy, not the one of the best evaluation (the default)")
  e.add_argument("--episodes", type=int, default=16)
  e.add_argument("--seed", type=int, default=0)
  e.add_argument("--video", default="runs/eval/policy.mp4")
  p = sub.add_parser("demo", help="batched random rollout, env steps/s, and a video")
  p.add_argument("--env", default="Hopper", help="a robot, or a task of your own as module:Class")
  p.add_argument("--num-envs", type=int, default=1024)
  p.add_argument("--steps", type=int, default=500, help="steps of every env")
  p.add_argument("--seed", type=int, default=0)
  p.add_argument("--out", default="runs/demo")
  return parser


def _add_run_flags(t: argparse.ArgumentParser, sweep: bool = False) -> None:
  """The flags of a training run, shared by train and sweep."""
  t.add_argument("--env", default="Hopper",
                 help="a robot (Hopper, Walker2D, HalfCheetah, Ant, Humanoid), or a task of your "
                      "own as module:Class, a subclass of one (the module is looked for in the "
                      "current directory and on sys.path)")
  t.add_argument("--env-set", action="append", default=[], metavar="NAME=VALUE",
                 help="a constructor setting of the task, e.g. --env-set height_weight=5.0 "
                      "(repeatable); recorded in the checkpoint")
  t.add_argument("--agent", default=None, help="d4pg (default), ddpg, mpo or dmpo")
  t.add_argument("--preset", default="cpu",
                 help="named settings: cpu or gpu (the robot's, mjx_hopper.presets, for its "
                      "agent; the agent's own for another), or the agent's seed")
  t.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                 help=("a setting for every member, or a dynamic one's values to sweep, e.g. "
                       "--set learning_rate=1e-4,3e-4 (repeatable)") if sweep else
                 "override one agent setting, e.g. --set sigma=0.2 (repeatable)")
  t.add_argument("--steps", type=int, default=1_000_000, help="total env steps")
  t.add_argument("--max-minutes", type=float, default=None,
                 help="also stop (and save) after this much wall-clock time")
  t.add_argument("--stop-at-return", type=float, default=None, metavar="RETURN",
                 help="also stop once an evaluation (of every member) reaches RETURN")
  # The trainer's layout: by default the preset's (for cpu, 512 envs, unroll 4, batch 256,
  # replay ratio 4, replay 1M, 20k before learning, 25 iterations per chunk).
  t.add_argument("--num-envs", type=int, default=None)
  t.add_argument("--unroll-length", type=int, default=None,
                 help="env steps per env per iteration")
  t.add_argument("--batch-size", type=int, default=None)
  t.add_argument("--replay-ratio", type=float, default=None,
                 help="samples drawn per transition inserted")
  t.add_argument("--replay-size", type=int, default=None)
  t.add_argument("--min-replay", type=int, default=None)
  t.add_argument("--chunk", type=int, default=None, help="iterations per compiled chunk")
  t.add_argument("--eval-every", type=int, default=None,
                 help="env steps between evaluations (cpu: 200,000)")
  t.add_argument("--eval-episodes", type=int, default=16)
  t.add_argument("--eval-on", choices=("auto", "host", "train"), default="auto",
                 help="where evaluations run: host, on the CPU beside training; train, on the "
                      "training's devices, which wait for them; auto (default): host for a "
                      "single run on an accelerator (a GPU), else train")
  t.add_argument("--episode-steps", type=int, default=None,
                 help="steps before an episode is truncated (default: the task's; PyBullet's "
                      "1000 for the robots)")
  t.add_argument("--seed", type=int, default=0)
  t.add_argument("--out", default="runs/sweep" if sweep else "runs/train",
                 help="folder for log.csv and config.json")
  t.add_argument("--checkpoint-dir", default=None,
                 help="checkpoints (default OUT/checkpoints); resumes when it holds one")
  t.add_argument("--checkpoint-minutes", type=float, default=10.0)
  t.add_argument("--log-every", type=float, default=10.0, help="seconds between log lines")
  t.add_argument("--tensorboard", default=None, metavar="DIR",
                 help="also write log.csv's scalars to DIR as TensorBoard events")
  t.add_argument("--no-progress", action="store_true", help="no progress bar")


def main(argv: list[str] | None = None) -> None:
  parser = build_parser()
  args = parser.parse_args(argv)
  if os.getcwd() not in sys.path:  # as `python -m` does: --env my_events:Jump finds ./my_events.py
    sys.path.insert(0, os.getcwd())
  _setup_jax(args.cpu_devices)
  if args.command == "train":
    train(args)
  elif args.command == "sweep":
    sweep(args)
  elif args.command == "extract":
    extract(args)
  elif args.command == "eval":
    evaluate(args)
  elif args.command == "demo":
    from mjx_hopper import envs
    try:
      envs.task_class(args.env)
    except ValueError as error:
      parser.error(f"unknown --env {args.env!r}; choose from {envs.list_envs()}, or a task of your "
                   "own as module:Class" if ":" not in args.env else str(error))
    if args.num_envs < 1 or args.steps < 1:
      parser.error("--num-envs and --steps must be >= 1")
    try:
      demo(args)
    except ValueError as error:  # the task's reward (envs.check_task)
      parser.error(str(error))


if __name__ == "__main__":
  main(sys.argv[1:])
