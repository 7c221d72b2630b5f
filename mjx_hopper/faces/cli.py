"""The `mjx-hopper` command line.

    mjx-hopper train [--env Hopper] [--agent d4pg|ddpg|mpo|dmpo] [--preset cpu|gpu] [--out-dir DIR]
    mjx-hopper train --env my_events:HighJump --env-set height_weight=5.0   # a task of your own
    mjx-hopper sweep --seeds 4 --set learning_rate=1e-4,3e-4 [train's flags]
    mjx-hopper extract --checkpoint DIR --member 3|best --out DIR
    mjx-hopper eval --checkpoint DIR [--member M|best] [--episodes 16] [--video out.mp4]
    mjx-hopper eval --policy policy.npz | --pretrained Humanoid [--video out.mp4]
    mjx-hopper export --checkpoint DIR [--member M|best] [--latest] --out policy.npz
    mjx-hopper plot RUN [RUN ...] [--out curves.png] [--x env_steps|wall_s]
    mjx-hopper settings [--agent d4pg] [--env Hopper --preset gpu]
    mjx-hopper demo [--env Hopper] [--num-envs 1024] [--steps 500] [--out runs/demo]

--cpu-devices N, before or after the command, splits the CPU into N devices (default: one per
core).
"""

from __future__ import annotations

import argparse
import os
import sys

import mjx_hopper


VIDEO = "runs/eval/policy.mp4"  # eval's video, unless --video names another


def main(argv: list[str] | None = None) -> None:
  """Runs the command line `argv` (default: the process's); a user's error ends it in one line."""
  argv = sys.argv[1:] if argv is None else argv
  try:
    mjx_hopper.setup(cpu_devices=_cpu_devices(argv))  # before the parser imports JAX
  except ValueError as error:  # JAX started with other CPU devices (main called in a process)
    raise SystemExit(f"mjx-hopper: {error}") from None
  if os.getcwd() not in sys.path:  # as `python -m` does: --env my_events:Jump finds ./my_events.py
    sys.path.insert(0, os.getcwd())
  args = build_parser().parse_args(argv)
  try:
    if getattr(args, "help", False):  # train's or sweep's, once every flag is read
      from mjx_hopper.settings import flags
      bases = {args.command: flags.base_config(args, args.command)}
      build_parser(bases).parse_args([args.command]).parser.print_help()
      return
    if args.cpu_devices < 1:
      raise ValueError(f"--cpu-devices must be >= 1, got {args.cpu_devices}")
    args.func(args)
  except (ValueError, FileNotFoundError) as error:
    raise SystemExit(f"mjx-hopper {args.command}: {error}") from None


def build_parser(bases: dict | None = None) -> argparse.ArgumentParser:
  """The command line. `bases` ({"train": RunConfig, "sweep": RunConfig}) are the configs whose
  values --help shows as the defaults a run would use."""
  parser = argparse.ArgumentParser(prog="mjx-hopper", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  _add_cpu_devices(parser, os.cpu_count() or 1)
  sub = parser.add_subparsers(dest="command", required=True)
  for name, (func, help, add_flags) in COMMANDS.items():
    # train's and sweep's --help waits for the whole line (`main`)
    p = sub.add_parser(name, help=help, description=func.__doc__,
                       add_help=name not in ("train", "sweep"))
    _add_cpu_devices(p, argparse.SUPPRESS)  # the global flag, after the command too
    p.set_defaults(func=func, parser=p)
    add_flags(p, (bases or {}).get(name))
  return parser


def _settings_flags(g: argparse.ArgumentParser, _base) -> None:
  g.add_argument("--env", default="Hopper", help="a robot, or a task as module:Class")
  g.add_argument("--agent", default="d4pg")
  g.add_argument("--preset", default=None, help="the robot's cpu or gpu settings")
  g.set_defaults(config=None)


def _extract_flags(x: argparse.ArgumentParser, _base) -> None:
  x.add_argument("--checkpoint", required=True, help="the sweep's checkpoint directory")
  _add_member(x, required=True)
  x.add_argument("--out", required=True, help="folder for its checkpoints/ and config.json")


def _eval_flags(e: argparse.ArgumentParser, _base) -> None:
  source = e.add_mutually_exclusive_group(required=True)
  source.add_argument("--checkpoint", help="a checkpoint directory")
  source.add_argument("--policy", help="a policy file written by mjx-hopper export")
  source.add_argument("--pretrained", metavar="ROBOT",
                      help="the policy shipped for a robot (Hopper, ..., Humanoid)")
  _add_member(e, default=None)
  _add_latest(e)
  e.add_argument("--episodes", type=int, default=16)
  e.add_argument("--seed", type=int, default=0)
  e.add_argument("--video", default=None, metavar="FILE",
                 help=f"the mp4 of episode 0 (default: {VIDEO}; none for --pretrained)")
  _add_task(e)


def _export_flags(o: argparse.ArgumentParser, _base) -> None:
  o.add_argument("--checkpoint", required=True, help="a checkpoint directory")
  _add_member(o, default=None)
  _add_latest(o)
  o.add_argument("--out", required=True, help="the .npz file to write")
  o.add_argument("--onnx", default=None, metavar="FILE", help="also write it as an ONNX model")
  _add_task(o)


def _plot_flags(c: argparse.ArgumentParser, _base) -> None:
  c.add_argument("runs", nargs="+", metavar="RUN",
                 help="a run's or a sweep's folder (its out_dir, holding log.csv)")
  c.add_argument("--out", default=None, metavar="FILE",
                 help="the PNG to write (default: RUN/curves.png for one run, else curves.png)")
  c.add_argument("--x", default="env_steps", choices=("env_steps", "wall_s"),
                 help="the horizontal axis: env steps, or wall time summed over resumptions")


def _demo_flags(d: argparse.ArgumentParser, _base) -> None:
  d.add_argument("--env", default="Hopper", help="a robot, or a task of your own as module:Class")
  d.add_argument("--num-envs", type=int, default=1024)
  d.add_argument("--steps", type=int, default=500, help="steps of every env")
  d.add_argument("--seed", type=int, default=0)
  d.add_argument("--out", default="runs/demo")


def _add_cpu_devices(parser: argparse.ArgumentParser, default) -> None:
  parser.add_argument("--cpu-devices", type=int, default=default,
                      help="XLA CPU devices to split the env batch over (default: all cores)")


def _add_member(parser: argparse.ArgumentParser, **kwargs) -> None:
  parser.add_argument("--member", type=_member, **kwargs,
                      help="a sweep's member: its index (log.csv's member), or best: the member "
                           "of the best evaluation; a single run's needs none")


def _add_latest(parser: argparse.ArgumentParser) -> None:
  parser.add_argument("--latest", action="store_true",
                      help="the latest policy, not the one of the best evaluation (the default)")


def _add_task(parser: argparse.ArgumentParser) -> None:
  parser.add_argument("--env", default=None, metavar="MODULE:CLASS",
                      help="the run's task, for one that cannot be imported")


def _member(text: str) -> int | str:
  """--member: an index, or "best"."""
  if text == "best":
    return text
  try:
    return int(text)
  except ValueError:
    raise argparse.ArgumentTypeError(f"takes a member's index or 'best', got {text!r}") from None


def _run_flags(t: argparse.ArgumentParser, base, sweep: bool = False) -> None:
  from mjx_hopper.settings import flags
  flags.add_run_flags(t, base, sweep)


def train(args: argparse.Namespace) -> None:
  """Trains an agent: progress, log.csv, checkpoints, evaluations and curves.png."""
  from mjx_hopper.run import loop
  loop.run(_run_config(args, "train"), checkpoint_dir=args.checkpoint_dir,
           progress=not args.no_progress)


def sweep(args: argparse.Namespace) -> None:
  """Trains a sweep's members at once: log.csv (a row per member per chunk and evaluation),
  curves.png, a ranking, checkpoints; with --distributed, over several processes as one."""
  from mjx_hopper.process import distributed
  from mjx_hopper.run import loop
  if args.seeds is not None and args.seeds < 1:
    raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
  cluster = distributed.Cluster(args.coordinator, args.num_processes, args.process_id)
  if any(v is not None for v in cluster) and not args.distributed:
    raise ValueError("--coordinator, --num-processes and --process-id place a process of a "
                     "--distributed sweep: add --distributed")
  loop.run(_run_config(args, "sweep"), checkpoint_dir=args.checkpoint_dir,
           progress=not args.no_progress, distributed_run=args.distributed and cluster)


def _run_config(args: argparse.Namespace, command: str):
  """`command`'s RunConfig from its flags, saying in a line where its budget is not measured."""
  from mjx_hopper.settings import flags
  cfg = flags.run_config(args, command)  # a bad flag ends the command before the line
  if line := flags.unmeasured_budget(args):
    print(f"mjx-hopper {command}: {line}")
  return cfg


def settings(args: argparse.Namespace) -> None:
  """Prints every setting: its flag, type, default, the preset's value, and whether a sweep can
  vary it in one compiled program."""
  from mjx_hopper import agents
  from mjx_hopper.settings import config, flags
  base = flags.base_config(args, "train")
  rows = config.settings_table(base, [f for _, f in flags.fields()],
                               f"{base.task_id} {args.preset or 'cpu'}")
  widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
  print(f"{base.agent} ({base.agent_defaults}); agents: {', '.join(agents.list_agents())}")
  for row in rows:
    print("  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip())


def extract(args: argparse.Namespace) -> None:
  """Writes one member of a sweep's checkpoint as a single run's checkpoint."""
  from mjx_hopper.run import checkpoints
  checkpoints.extract(args.checkpoint, args.member, args.out)


def export(args: argparse.Namespace) -> None:
  """Writes a checkpoint's policy as one file that runs with NumPy alone (and as ONNX)."""
  from mjx_hopper.faces import export as export_lib
  path = export_lib.export_checkpoint(args.checkpoint, args.out, member=args.member,
                                      which="latest" if args.latest else "best", env=args.env)
  if args.onnx:
    from mjx_hopper.faces import export_onnx
    print(f"ONNX: {export_onnx.write(path, args.onnx)}")


def evaluate(args: argparse.Namespace) -> None:
  """Evaluates the policy of a checkpoint, an exported file or a pretrained robot, and films
  episode 0."""
  from mjx_hopper.faces import export as export_lib
  if args.pretrained is not None:
    export_lib.evaluate_file(export_lib.pretrained_path(args.pretrained), args.episodes,
                             args.seed, args.video, env=args.env)
  elif args.policy is not None:
    export_lib.evaluate_file(args.policy, args.episodes, args.seed, args.video or VIDEO,
                             env=args.env)
  else:
    from mjx_hopper.run import checkpoints
    checkpoints.evaluate_checkpoint(args.checkpoint, args.member, args.episodes, args.seed,
                             args.video or VIDEO, which="latest" if args.latest else "best",
                             env=args.env)


def plot(args: argparse.Namespace) -> None:
  """Draws the learning curves of runs, or of a sweep's members, on one figure."""
  from mjx_hopper.run import curves
  out = args.out or (os.path.join(args.runs[0], "curves.png") if len(args.runs) == 1
                     else "curves.png")
  print(f"learning curves: {curves.plot_runs(args.runs, out, args.x)}")


def demo(args: argparse.Namespace) -> None:
  """Batched random-action rollout: prints env steps/s, writes an mp4 of one episode."""
  from mjx_hopper.core import rollout
  if args.num_envs < 1 or args.steps < 1:
    raise ValueError("--num-envs and --steps must be >= 1")
  rollout.demo(args.env, args.num_envs, args.steps, args.seed, args.out)


# Each command: (what it does, its line in --help, what adds its flags).
COMMANDS = {
    "train": (train, "train an agent (progress, log, checkpoints, evaluations, curves)",
              _run_flags),
    "sweep": (sweep, "train many seeds and settings at once, in one program",
              lambda w, base: _run_flags(w, base, sweep=True)),
    "settings": (settings, "list every setting, its default and the preset's value",
                 _settings_flags),
    "extract": (extract, "write one member of a sweep as a single run's checkpoint",
                _extract_flags),
    "eval": (evaluate, "evaluate a checkpoint's, an exported or a pretrained policy, and film "
             "it", _eval_flags),
    "export": (export, "write a checkpoint's policy as one file for NumPy", _export_flags),
    "plot": (plot, "draw runs' (or a sweep's) learning curves on one figure", _plot_flags),
    "demo": (demo, "batched random rollout, env steps/s, and a video", _demo_flags),
}


def _cpu_devices(argv: list[str]) -> int | None:
  """--cpu-devices's value in `argv`, read before the parser, which imports JAX. None where it
  is not given (`setup`'s default: one per core, as `loop.run` gets) or not an integer >= 1,
  which the parser then refuses."""
  pre = argparse.ArgumentParser(add_help=False)
  pre.add_argument("--cpu-devices", default=None)
  value = pre.parse_known_args(argv)[0].cpu_devices
  return int(value) if value and value.isdigit() and int(value) >= 1 else None


if __name__ == "__main__":
  main()
