"""The `mjx-hopper` command line.

    mjx-hopper train [--env Hopper] [--agent d4pg|ddpg|mpo|dmpo] [--preset cpu|gpu] [--out DIR]
    mjx-hopper train --env my_events:HighJump --env-set height_weight=5.0   # a task of your own
    mjx-hopper sweep --seeds 4 --set learning_rate=1e-4,3e-4 [train's flags]
    mjx-hopper extract --checkpoint DIR --member 3 --out DIR
    mjx-hopper eval --checkpoint DIR [--member 0] [--episodes 16] [--video out.mp4]
    mjx-hopper export --checkpoint DIR [--member M] [--latest] --out policy.npz
    mjx-hopper eval --policy policy.npz [--video out.mp4]
    mjx-hopper settings [--agent d4pg] [--env Hopper --preset gpu]
    mjx-hopper demo [--env Hopper] [--num-envs 1024] [--steps 500] [--out runs/demo]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time


def _quiet_xla() -> None:
  """XLA's C++ log at errors only, where this process may use XLA's GSPMD partitioner
  (`parallel.SHARDY_CRASHES`): GSPMD warns at every compile that it is deprecated, and XLA
  offers no way to silence that one line. XLA reads it when JAX is first imported, so this
  runs before; a TF_CPP_MIN_LOG_LEVEL already set wins."""
  import importlib.metadata
  version = tuple(int(p) for p in importlib.metadata.version("jax").split(".")[:2])
  if version >= (0, 11):  # parallel.SHARDY_CRASHES, read without importing JAX
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")


def _setup_jax(cpu_devices: int) -> None:
  """Splits the CPU into `cpu_devices` XLA devices and turns on the persistent compile cache,
  before JAX starts its backends."""
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
        f"control dt {env.dt} s; devices: {jax.devices()}")
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
  os.makedirs(args.out, exist_ok=True)
  path = render.write_mp4(os.path.join(args.out, f"{args.env.lower()}_random.mp4"),
                          env.render(np.asarray(stats["qpos"][:length + 1])), fps=1 / env.dt)
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


def _sweep_settings(pairs: list[str], agent: str, agent_preset: str) -> tuple[dict, dict]:
  """(fixed settings, grid) of a sweep's --set pairs: a dynamic setting given several
  comma-separated values (name=v1,v2) is swept; any other is one value for every member."""
  from mjx_hopper import config
  dynamic = set(config.dynamic_settings(agent, agent_preset))
  fixed, grid = {}, {}
  for name, value in _overrides(pairs).items():
    if isinstance(value, tuple) and (name in dynamic or any(isinstance(v, tuple) for v in value)):
      grid[name] = value
    else:
      fixed[name] = value
  return fixed, grid


def _run_flags():
  """(owner, field) of every setting offered as a flag: RunConfig's, then TrainConfig's."""
  from mjx_hopper.config import RunConfig
  from mjx_hopper.train import TrainConfig
  return [(owner, f) for owner in (RunConfig, TrainConfig) for f in dataclasses.fields(owner)
          if f.metadata.get("flag")]


def flag_name(field) -> str:
  return "--" + field.name.replace("_", "-")


def _parse_value(hint: str):
  """The argparse type of a field's type hint (text, under `from __future__`)."""
  return {"int": int, "float": float}.get(hint.split(" |")[0], str)


def _base_config(args: argparse.Namespace, command: str):
  """The config a run starts from: a saved config (--config), else the robot's preset
  (--preset) of the agent (--agent) on the task (--env)."""
  from mjx_hopper import config, presets
  if args.config is not None:
    for flag in ("preset", "agent_preset"):
      if getattr(args, flag, None) is not None:
        raise ValueError(f"--{flag.replace('_', '-')} and --config both choose the settings: "
                         "give one of them")
    cfg = config.load(args.config)
    if command == "train" and (cfg.seeds or cfg.grid or cfg.pbt):
      raise ValueError(f"{args.config} is a sweep's config: run it with mjx-hopper sweep "
                       "--config")
    return cfg
  base = presets.agent_run_config(getattr(args, "env", "Hopper"), args.preset or "cpu",
                                  getattr(args, "agent", "d4pg"))
  return dataclasses.replace(base, out_dir="runs/sweep") if command == "sweep" else base


def _run_config(args: argparse.Namespace, command: str = "train"):
  """The RunConfig of train's (and sweep's) flags: the base config (`_base_config`), then every
  flag given explicitly, --set and --env-set."""
  from mjx_hopper.train import TrainConfig
  base = _base_config(args, command)
  given = {f.name: getattr(args, f.name) for _, f in _run_flags() if hasattr(args, f.name)}
  train_given = {k: v for k, v in given.items()
                 if k in {f.name for f in dataclasses.fields(TrainConfig)}}
  run_given = {k: v for k, v in given.items() if k not in train_given}
  agent = run_given.get("agent", base.agent)
  agent_preset = run_given.get("agent_preset", base.agent_preset)
  fixed, grid = (_sweep_settings(args.set, agent, agent_preset) if command == "sweep"
                 else (_overrides(args.set), {}))
  if "replay_ratio" in fixed:
    train_given["replay_ratio"] = fixed.pop("replay_ratio")
  sweep = {}
  if command == "sweep":
    seed = run_given.get("seed", base.seed)
    seeds = (tuple(range(seed, seed + args.seeds)) if args.seeds is not None
             else base.seeds or (seed,))
    sweep = dict(seeds=seeds, grid={**base.grid, **grid}, pbt=_pbt(args) or base.pbt)
  return dataclasses.replace(
      base, **run_given, **sweep, train=dataclasses.replace(base.train, **train_given),
      env_settings={**base.env_settings, **_overrides(args.env_set, "--env-set")},
      agent_overrides={**base.agent_overrides, **fixed})


def train(args: argparse.Namespace) -> None:
  """Trains an agent, with progress, a CSV log, checkpoints and a final evaluation."""
  from mjx_hopper import loop
  try:
    cfg = _run_config(args, "train")
    loop.run(cfg, checkpoint_dir=args.checkpoint_dir, progress=not args.no_progress)
  except ValueError as error:
    raise SystemExit(f"mjx-hopper train: {error}")


def sweep(args: argparse.Namespace) -> None:
  """Trains a sweep's members at once: log.csv (a row per member per chunk and evaluation),
  curves.png, a ranking, checkpoints; over several processes, each its share."""
  from mjx_hopper import loop, parallel
  try:
    if args.seeds is not None and args.seeds < 1:
      raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    process = None
    if args.distributed or args.coordinator or args.num_processes or args.process_id is not None:
      process = parallel.join_processes(args.coordinator, args.num_processes, args.process_id)
    cfg = _run_config(args, "sweep")
    loop.run(cfg, checkpoint_dir=args.checkpoint_dir, progress=not args.no_progress,
             process=process)
  except ValueError as error:
    raise SystemExit(f"mjx-hopper sweep: {error}")


def _pbt(args: argparse.Namespace):
  """The PBT of sweep's --pbt flags (None without --pbt)."""
  from mjx_hopper.pbt import PBT
  given = [flag for flag, value in (("--pbt-every", args.pbt_every),
                                    ("--pbt-fraction", args.pbt_fraction),
                                    ("--pbt-bounds", args.pbt_bounds)) if value]
  if not args.pbt:
    if given:
      raise ValueError(f"{', '.join(given)} set(s) population-based training: add --pbt")
    return None
  settings = dict(every=args.pbt_every, fraction=args.pbt_fraction,
                  bounds=_overrides(args.pbt_bounds, "--pbt-bounds"))
  return PBT(**{k: v for k, v in settings.items() if v is not None})


def settings(args: argparse.Namespace) -> None:
  """Prints every setting: its flag, type, default, the preset's value, and whether a sweep can
  vary it in one compiled program."""
  from mjx_hopper import agents, config
  base = _base_config(args, "train")
  rows = config.settings_table(base, [f for _, f in _run_flags()],
                               f"{base.task_id} {args.preset or 'cpu'}")
  widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
  print(f"{base.agent} ({base.agent_preset}); agents: {', '.join(agents.list_agents())}")
  for row in rows:
    print("  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip())


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


def export(args: argparse.Namespace) -> None:
  """Writes a checkpoint's policy as one file that runs with NumPy alone (and as ONNX)."""
  from mjx_hopper import export as export_lib
  try:
    path = export_lib.export_checkpoint(args.checkpoint, args.out, member=args.member,
                                        which="latest" if args.latest else "best", env=args.env)
    if args.onnx:
      from mjx_hopper import export_onnx
      print(f"ONNX: {export_onnx.write(path, args.onnx)}")
  except (ValueError, FileNotFoundError) as error:
    raise SystemExit(f"mjx-hopper export: {error}")


def evaluate(args: argparse.Namespace) -> None:
  """Loads the policy of a checkpoint (or an exported file), evaluates it and writes an mp4 of
  one episode."""
  import jax
  import numpy as np

  from mjx_hopper import loop, train as train_lib
  from mjx_hopper.envs import render
  if args.policy is not None:
    from mjx_hopper import export as export_lib
    try:
      export_lib.evaluate_file(args.policy, args.episodes, args.seed, args.video, env=args.env)
    except (ValueError, FileNotFoundError) as error:
      raise SystemExit(f"mjx-hopper eval: {error}")
    return
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
  print(f"{cfg.task_id} / {cfg.agent}: return {returns.mean():.1f} +- {returns.std():.1f}, length "
        f"{np.mean(result['length']):.0f} over {args.episodes} episodes")
  length = int(result["length"][0])
  frames = render.render_frames(trainer.env.mj_model, np.asarray(result["qpos"][:length + 1]))
  path = render.write_mp4(args.video, frames, fps=1 / trainer.env.dt)
  print(f"video of episode 0 ({length} steps, return {returns[0]:.1f}): {path}")


def build_parser(bases: dict | None = None) -> argparse.ArgumentParser:
  """The command line. `bases` ({"train": RunConfig, "sweep": RunConfig}) are the configs whose
  values --help shows as the defaults a run would use."""
  parser = argparse.ArgumentParser(prog="mjx-hopper", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1,
                      help="XLA CPU devices to split the env batch over (default: all cores)")
  sub = parser.add_subparsers(dest="command", required=True)
  t = sub.add_parser("train", help="train an agent (progress, CSV log, checkpoints, evaluation)")
  _add_run_flags(t, (bases or {}).get("train"))
  w = sub.add_parser("sweep", help="train many seeds and settings at once, in one program")
  _add_run_flags(w, (bases or {}).get("sweep"), sweep=True)
  w.add_argument("--seeds", type=int, default=None,
                 help="members per setting: seeds SEED to SEED+N-1 (becomes the config's "
                      "seeds; default 1, or a --config's seeds)")
  w.add_argument("--distributed", action="store_true",
                 help="a sweep over processes, each told its place by its launcher (SLURM, "
                      "Open MPI): each trains its share of the members")
  w.add_argument("--coordinator", default=None, help="accepted for older command lines")
  w.add_argument("--num-processes", type=int, default=None, help="a sweep over processes")
  w.add_argument("--process-id", type=int, default=None, help="this process's index")
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
  g = sub.add_parser("settings", help="list every setting, its default and the preset's value")
  g.add_argument("--env", default="Hopper", help="a robot, or a task as module:Class")
  g.add_argument("--agent", default="d4pg")
  g.add_argument("--preset", default=None, help="the robot's cpu or gpu settings")
  g.set_defaults(config=None)
  x = sub.add_parser("extract", help="write one member of a sweep as a single run's checkpoint")
  x.add_argument("--checkpoint", required=True, help="the sweep's checkpoint directory")
  x.add_argument("--member", type=_member, required=True,
                 help="the member's index (log.csv), or best: the member of the best evaluation")
  x.add_argument("--out", required=True, help="folder for its checkpoints/ and config.json")
  e = sub.add_parser("eval", help="evaluate a checkpoint's or an exported policy, and film it")
  source = e.add_mutually_exclusive_group(required=True)
  source.add_argument("--checkpoint", help="a checkpoint directory")
  source.add_argument("--policy", help="a policy file written by mjx-hopper export")
  e.add_argument("--env", default=None, metavar="MODULE:CLASS",
                 help="the task of an exported policy whose task cannot be imported")
  e.add_argument("--member", type=int, default=0, help="which member of a sweep's checkpoint")
  e.add_argument("--latest", action="store_true",
                 help="the latest policy, not the one of the best evaluation (the default)")
  e.add_argument("--episodes", type=int, default=16)
  e.add_argument("--seed", type=int, default=0)
  e.add_argument("--video", default="runs/eval/policy.mp4")
  o = sub.add_parser("export", help="write a checkpoint's policy as one file for NumPy")
  o.add_argument("--checkpoint", required=True, help="a checkpoint directory")
  o.add_argument("--member", type=_member, default=None,
                 help="a sweep's member: its index, or best (required for a sweep)")
  o.add_argument("--latest", action="store_true",
                 help="the latest policy, not the one of the best evaluation (the default)")
  o.add_argument("--out", required=True, help="the .npz file to write")
  o.add_argument("--onnx", default=None, metavar="FILE", help="also write it as an ONNX model")
  o.add_argument("--env", default=None, metavar="MODULE:CLASS",
                 help="the run's task, for one that cannot be imported")
  p = sub.add_parser("demo", help="batched random rollout, env steps/s, and a video")
  p.add_argument("--env", default="Hopper", help="a robot, or a task of your own as module:Class")
  p.add_argument("--num-envs", type=int, default=1024)
  p.add_argument("--steps", type=int, default=500, help="steps of every env")
  p.add_argument("--seed", type=int, default=0)
  p.add_argument("--out", default="runs/demo")
  return parser


def _add_run_flags(t: argparse.ArgumentParser, base, sweep: bool = False) -> None:
  """train's and sweep's flags: one per setting of the config (its help, type and, as shown,
  the value `base` holds), and the conveniences that become settings. Only flags given
  explicitly replace the base config's values."""
  for owner, f in _run_flags():
    now = None if base is None else getattr(
        base if owner is type(base) else base.train, f.name)
    shown = "" if base is None else f" (default: {now})"
    t.add_argument(flag_name(f), *f.metadata["aliases"], dest=f.name,
                   type=_parse_value(str(f.type)), default=argparse.SUPPRESS,
                   help=f.metadata["help"] + shown)
  t.add_argument("--preset", default=None,
                 help="the robot's settings: cpu or gpu (mjx_hopper.presets); default cpu")
  t.add_argument("--config", default=None, metavar="FILE",
                 help="start from a run's saved config.json instead of a preset")
  t.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                 help=("an agent setting for every member, or a dynamic one's values to sweep "
                       "(name=v1,v2 becomes the grid); `mjx-hopper settings` lists them")
                 if sweep else "an agent setting (becomes agent_overrides), e.g. --set "
                 "sigma=0.2; `mjx-hopper settings` lists them")
  t.add_argument("--env-set", action="append", default=[], metavar="NAME=VALUE",
                 help="a constructor setting of the task (becomes env_settings), e.g. "
                      "--env-set height_weight=5.0")
  t.add_argument("--checkpoint-dir", default=None,
                 help="checkpoints (default OUT_DIR/checkpoints); resumes when it holds one")
  t.add_argument("--no-progress", action="store_true", help="no progress bar")


def _help_bases(argv: list[str]) -> dict | None:
  """The configs --help describes: those of the --env, --agent, --preset and --config given."""
  if "-h" not in argv and "--help" not in argv:
    return None
  pre = argparse.ArgumentParser(add_help=False)
  for flag in ("--env", "--agent", "--preset", "--config"):
    pre.add_argument(flag, default=None)
  known, _ = pre.parse_known_args(argv)
  args = argparse.Namespace(env=known.env or "Hopper", agent=known.agent or "d4pg",
                            preset=known.preset, config=known.config)
  try:
    return {command: _base_config(args, command) for command in ("train", "sweep")}
  except (ValueError, OSError):
    return None


def main(argv: list[str] | None = None) -> None:
  argv = sys.argv[1:] if argv is None else argv
  _quiet_xla()
  if os.getcwd() not in sys.path:  # as `python -m` does: --env my_events:Jump finds ./my_events.py
    sys.path.insert(0, os.getcwd())
  parser = build_parser(_help_bases(argv))
  args = parser.parse_args(argv)
  _setup_jax(args.cpu_devices)
  if args.command in ("train", "sweep"):
    (train if args.command == "train" else sweep)(args)
  elif args.command == "settings":
    try:
      settings(args)
    except ValueError as error:
      raise SystemExit(f"mjx-hopper settings: {error}")
  elif args.command == "extract":
    extract(args)
  elif args.command == "eval":
    evaluate(args)
  elif args.command == "export":
    export(args)
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
