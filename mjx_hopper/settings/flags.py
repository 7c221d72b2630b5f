"""train's and sweep's flags, one per setting of the config, and the RunConfig they describe: a
base config (the robot's preset, or a saved config.json), with only the flags given replacing
its values."""

from __future__ import annotations

import argparse
import ast
import dataclasses

from mjx_hopper.settings import config, presets
from mjx_hopper.settings.config import RunConfig
from mjx_hopper.settings.training import PBT, TrainConfig


def fields() -> list:
  """(owner, field) of every setting offered as a flag: RunConfig's, then TrainConfig's."""
  return [(owner, f) for owner in (RunConfig, TrainConfig) for f in dataclasses.fields(owner)
          if f.metadata.get("flag")]


def flag_name(field) -> str:
  """A config field's flag: its name with dashes, `--total-env-steps` for `total_env_steps`."""
  return "--" + field.name.replace("_", "-")


def add_run_flags(t: argparse.ArgumentParser, base, sweep: bool = False) -> None:
  """train's and sweep's flags: one per setting of the config (its help, type and, as shown,
  the value `base` holds), and the conveniences that become settings. Only flags given
  explicitly replace the base config's values."""
  t.add_argument("-h", "--help", action="store_true",
                 help="show this help, with the values of the run the other flags describe")
  for owner, f in fields():
    now = None if base is None else getattr(
        base if owner is type(base) else base.train, f.name)
    kind = {"int": int, "float": float}.get(str(f.type).split(" |")[0], str)
    t.add_argument(flag_name(f), dest=f.name, type=kind, default=argparse.SUPPRESS,
                   help=f.metadata["help"] + ("" if base is None else f" (default: {now})"))
  t.add_argument("--preset", default=None,
                 help="the robot's settings: cpu or gpu (mjx_hopper.settings.presets); default cpu")
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
  if sweep:
    _add_sweep_flags(t)


def _add_sweep_flags(w: argparse.ArgumentParser) -> None:
  w.add_argument("--seeds", type=int, default=None,
                 help="members per setting: seeds SEED to SEED+N-1 (becomes the config's "
                      "seeds; default 1, or a --config's seeds)")
  w.add_argument("--distributed", action="store_true",
                 help="one sweep over several processes (JAX's distributed runtime), each "
                      "told its place by its launcher (SLURM, Open MPI) or the next flags")
  w.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                 help="process 0's address for --distributed")
  w.add_argument("--num-processes", type=int, default=None, help="processes of --distributed")
  w.add_argument("--process-id", type=int, default=None,
                 help="this process's index under --distributed")
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


def base_config(args: argparse.Namespace, command: str) -> RunConfig:
  """The config a run starts from: a saved config (--config), else the robot's preset
  (--preset) of the agent (--agent) on the task (--env)."""
  if args.config is not None:
    for flag in ("preset", "agent_defaults"):
      if getattr(args, flag, None) is not None:
        raise ValueError(f"--{flag.replace('_', '-')} and --config both choose the settings: "
                         "give one of them")
    cfg = config.load(args.config)
    if command == "train" and (cfg.seeds or cfg.grid or cfg.pbt):
      raise ValueError(f"{args.config} is a sweep's config: run it with mjx-hopper sweep "
                       "--config")
    return cfg
  # An unmeasured budget is said by the CLI, after its flags (`unmeasured_budget` below).
  base = presets.agent_run_config(getattr(args, "env", "Hopper"), args.preset or "cpu",
                                  getattr(args, "agent", "d4pg"), warn=False)
  return dataclasses.replace(base, out_dir="runs/sweep") if command == "sweep" else base


def unmeasured_budget(args: argparse.Namespace) -> str | None:
  """`presets.unmeasured_budget`'s line for a run started from a preset whose budget no flag
  (--total-env-steps, --max-minutes) replaces; else None."""
  if args.config is not None or any(hasattr(args, name)
                                    for name in ("total_env_steps", "max_minutes")):
    return None
  kind = args.preset or "cpu"
  if getattr(args, "agent_defaults", kind) != kind:
    return (f"no budget is measured for the agent's {args.agent_defaults} defaults: it trains "
            f"for the {kind} preset's budget; set --total-env-steps or --max-minutes")
  return presets.unmeasured_budget(getattr(args, "env", "Hopper"), kind,
                                   getattr(args, "agent", "d4pg"))


def run_config(args: argparse.Namespace, command: str = "train") -> RunConfig:
  """The RunConfig of train's (and sweep's) flags: the base config (`base_config`), then every
  flag given explicitly, --set and --env-set."""
  base = base_config(args, command)
  given = {f.name: getattr(args, f.name) for _, f in fields() if hasattr(args, f.name)}
  train_names = {f.name for f in dataclasses.fields(TrainConfig)}
  train_given = {k: v for k, v in given.items() if k in train_names}
  run_given = {k: v for k, v in given.items() if k not in train_names}
  if "total_env_steps" in run_given:  # a step count given alone is the whole budget
    run_given.setdefault("max_minutes", None)
  fixed, grid = overrides(args.set), {}
  if command == "sweep":
    dynamic = config.dynamic_settings(run_given.get("agent", base.agent),
                                      run_given.get("agent_defaults", base.agent_defaults))
    grid = {name: value for name, value in fixed.items() if isinstance(value, tuple) and (
        name in dynamic or any(isinstance(v, tuple) for v in value))}
    fixed = {name: value for name, value in fixed.items() if name not in grid}
  if "replay_ratio" in fixed:
    train_given["replay_ratio"] = fixed.pop("replay_ratio")
  sweep = {}
  if command == "sweep":
    seed = run_given.get("seed", base.seed)
    seeds = (tuple(range(seed, seed + args.seeds)) if args.seeds is not None
             else base.seeds or (seed,))
    sweep = dict(seeds=seeds, grid={**base.grid, **grid}, pbt=pbt(args) or base.pbt)
  # Other agent defaults (acme's values) are those values, not the robot's settings over them.
  kept = (base.agent_overrides if run_given.get("agent_defaults", base.agent_defaults)
          == base.agent_defaults else {})
  return dataclasses.replace(
      base, **run_given, **sweep, train=dataclasses.replace(base.train, **train_given),
      env_settings={**base.env_settings, **overrides(args.env_set, "--env-set")},
      agent_overrides={**kept, **fixed})


def overrides(pairs: list[str], flag: str = "--set") -> dict:
  """name=value pairs as a dict; values are parsed as Python literals when they can be (a
  sweep's name=v1,v2 is a tuple)."""
  out = {}
  for pair in pairs:
    name, sep, value = pair.partition("=")
    if not sep:
      raise ValueError(f"{flag} takes name=value, got {pair!r}")
    try:
      out[name] = ast.literal_eval(value)
    except (ValueError, SyntaxError):
      out[name] = value
  return out


def pbt(args: argparse.Namespace) -> PBT | None:
  """The PBT of sweep's --pbt flags (None without --pbt)."""
  given = [flag for flag, value in (("--pbt-every", args.pbt_every),
                                    ("--pbt-fraction", args.pbt_fraction),
                                    ("--pbt-bounds", args.pbt_bounds)) if value]
  if not args.pbt:
    if given:
      raise ValueError(f"{', '.join(given)} set(s) population-based training: add --pbt")
    return None
  settings = dict(every=args.pbt_every, fraction=args.pbt_fraction,
                  bounds=overrides(args.pbt_bounds, "--pbt-bounds"))
  return PBT(**{k: v for k, v in settings.items() if v is not None})
