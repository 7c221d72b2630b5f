"""Batch sweeps: S members (seeds x values of dynamic settings) trained at once, as the leading
axis of one TrainState in one compiled program.

    from mjx_hopper import loop, sweep
    cfg = loop.RunConfig(env="Hopper", agent="d4pg", seeds=(0, 1, 2, 3),
                         grid={"learning_rate": (1e-4, 3e-4)}, out_dir="runs/sweep")
    result = loop.run(cfg)                       # 8 members; log.csv has one row per member
    print(sweep.ranking(result.history, cfg.grid))   # loop.run prints it, and
    sweep.plot(result.history, cfg.grid, "runs/sweep/curves.png")  # writes this, itself
    loop.extract("runs/sweep/checkpoints", member=3, out_dir="runs/member3")

A single run is a sweep of one member (no seeds or grid). Only dynamic settings can be swept:
the agent's `Config.DYNAMIC` (learning rates, discount, n-step, sigma, vmin/vmax, MPO's
epsilons, ...) and the trainer's replay_ratio. They are arrays in the TrainState, so one
compilation serves every value. Structural settings (network sizes, atoms, samples, num_envs,
batch_size, ...) shape the program: sweeping them is refused with an error that says to run one
sweep per value.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import time
from typing import Any

import jax
import numpy as np

from mjx_hopper import agents, checkpoint, train
from mjx_hopper.logger import RETURNS

TRAINER_DYNAMIC = ("replay_ratio",)


def dynamic_settings(agent: str, preset: str = "cpu") -> list[str]:
  """The names a sweep's grid may vary for this agent."""
  return sorted(type(agents.config(agent, preset)).DYNAMIC + TRAINER_DYNAMIC)


def check_grid(agent: str, preset: str, grid: dict, train_cfg: train.TrainConfig,
               overrides: dict | None = None) -> None:
  """Raises ValueError naming the first bad entry of `grid` ({name: sequence of values}): an
  unknown or structural name, an empty or repeated list, or a value the config refuses."""
  cfg = agents.config(agent, preset, **(overrides or {}))
  fields = {f.name for f in dataclasses.fields(cfg)} | {
      f.name for f in dataclasses.fields(train.TrainConfig)}
  allowed = dynamic_settings(agent, preset)
  for name, values in grid.items():
    if name not in fields:
      raise ValueError(f"unknown setting {name!r} in the sweep; settings that can be swept are "
                       f"{allowed}")
    if name not in allowed:
      raise ValueError(f"{name!r} is structural (it shapes the compiled program) and cannot be "
                       f"swept in one program: run one sweep per value; settings that can be "
                       f"swept are {allowed}")
    if not isinstance(values, (list, tuple)) or not values:
      raise ValueError(f"the sweep's {name!r} needs a non-empty list of values, got {values!r}")
    if len(set(values)) != len(values):
      raise ValueError(f"the sweep's {name!r} repeats a value: {list(values)}")
    for value in values:
      if name in TRAINER_DYNAMIC:
        dataclasses.replace(train_cfg, **{name: value}).check()
      else:
        agents.config(agent, preset, **{**(overrides or {}), name: value})


def members(seeds: tuple[int, ...], grid: dict) -> list[dict[str, Any]]:
  """Every member's seed and swept values, in member order: the grid's combinations in the
  order given (the last name varying fastest), each with every seed."""
  names = list(grid)
  out = []
  for combo in itertools.product(*(grid[n] for n in names)):
    for seed in seeds:
      out.append({"seed": seed, **dict(zip(names, combo))})
  return out


def final_evaluations(rows: list[dict]) -> dict[int, float]:
  """{member: its last evaluation's mean return} from a run's log rows."""
  out = {}
  for row in rows:
    if row.get("kind") == "eval":
      out[int(row.get("member", 0))] = float(row["eval_return"])
  return out


def ranking(rows: list[dict], grid: dict) -> str:
  """A table of the grid's value combinations, best first by the mean over seeds of the
  members' last evaluation: mean, 95% interval of the mean, and each seed's return."""
  last = final_evaluations(rows)
  meta = {int(r.get("member", 0)): r for r in rows if r.get("kind") == "eval"}
  groups: dict[str, list[float]] = {}
  for member, value in sorted(last.items()):
    groups.setdefault(_group_label(meta[member], grid), []).append(value)
  lines = ["| rank | setting | mean return | 95% interval | seeds |", "|---|---|---|---|---|"]
  order = sorted(groups.items(), key=lambda kv: -np.mean(kv[1]))
  for rank, (name, values) in enumerate(order, 1):
    mean, half = _mean_interval(values)
    lines.append(f"| {rank} | {name or '(all)'} | {mean:.1f} | ±{half:.1f} | "
                 f"{', '.join(f'{v:.0f}' for v in values)} |")
  return "\n".join(lines)


def plot(rows: list[dict], grid: dict, path: str) -> str:
  """Learning curves to a PNG: per value combination, the mean evaluation return over seeds
  against env steps, with its 95% interval as a band. Returns the path."""
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt

  curves: dict[str, dict[float, list[float]]] = {}
  for row in rows:
    if row.get("kind") == "eval":
      curve = curves.setdefault(_group_label(row, grid), {})
      curve.setdefault(float(row["env_steps"]), []).append(float(row["eval_return"]))
  fig, ax = plt.subplots(figsize=(7, 4.5))
  for name, curve in sorted(curves.items()):
    steps = sorted(curve)
    stats = np.array([_mean_interval(curve[s]) for s in steps])
    ax.plot(steps, stats[:, 0], label=name or "mean over seeds")
    ax.fill_between(steps, stats[:, 0] - stats[:, 1], stats[:, 0] + stats[:, 1], alpha=0.25)
  ax.set_xlabel("env steps")
  ax.set_ylabel("evaluation return")
  ax.grid(alpha=0.3)
  ax.legend(fontsize=8)
  fig.tight_layout()
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  fig.savefig(path, dpi=100)
  plt.close(fig)
  return path


def _group_label(row: dict, grid: dict) -> str:
  """A log row's swept values as text (the CSV gives them back as strings)."""
  return " ".join(f"{name}={float(row[name]):g}" for name in grid)


def _mean_interval(values: list[float]) -> tuple[float, float]:
  """Mean and the half-width of its 95% interval (normal approximation; 0 for one value)."""
  values = np.asarray(values, np.float64)
  if len(values) < 2:
    return float(values.mean()), 0.0
  return float(values.mean()), float(1.96 * values.std(ddof=1) / math.sqrt(len(values)))


class Report:
  """What a run shows of its members. A single run (`single`) prints the logger's own lines;
  a sweep's rows (one per member) go to the files only, its terminal lines sum them up (the
  best member and the mean), and at the end it prints the ranking and draws the curves."""

  def __init__(self, grid: dict, members: list[dict], indices: list[int], say,
               single: bool):
    self.grid, self.members, self.indices, self.say = grid, members, indices, say
    self.single = single
    self.last_line = -float("inf")
    self.logger_print = say if single else (lambda line: None)
    self.id_fields = () if single else ("member", *members[0])

  def tags(self, m: int) -> dict:
    """The columns that name member m of this process (none in a single run)."""
    return {} if self.single else {"member": self.indices[m], **self.members[m]}

  def trained(self, env_steps: int, rate: float, returns, time_delta: float) -> None:
    """A sweep's train line, every `time_delta` seconds."""
    if not self.single and time.monotonic() - self.last_line >= time_delta:
      self.last_line = time.monotonic()
      self.say(f"[train] {env_steps:,} env steps | {rate:,.0f} steps/s (all members) | train "
               "return " + self.members_line(returns))

  def evaluated(self, env_steps: int, returns) -> None:
    """A sweep's evaluation line (a single run's is the logger's)."""
    if not self.single:
      self.say(f"[eval] {env_steps:,} env steps | " + self.members_line(returns))

  def status(self, rate: float, logger) -> str:
    """The progress bar's text."""
    return logger.describe(RETURNS, sep=", ") if self.single else f"{rate:,.0f} steps/s"

  def members_line(self, values) -> str:
    """'best 2,480 (seed=1 learning_rate=0.0003), mean 1,920' over finite values."""
    values = np.asarray(values, np.float64)
    if not np.isfinite(values).any():
      return "none yet"
    best = int(np.nanargmax(np.where(np.isfinite(values), values, -np.inf)))
    name = " ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                    for k, v in self.members[best].items() if k == "seed" or k in self.grid)
    return f"best {values[best]:,.1f} ({name}), mean {np.nanmean(values):,.1f}"

  def finish(self, rows: list[dict], out_dir: str) -> None:
    """A sweep's ranking and learning curves."""
    if not self.single:
      self.say("ranking by the last evaluation (mean over seeds):\n" + ranking(rows, self.grid))
      self.say(f"learning curves: {plot(rows, self.grid, os.path.join(out_dir, 'curves.png'))}")


def write_member(cfg, state, indices: list[int], member: int, out_dir: str) -> str:
  """Writes member `member` of a sweep's restored `state` (which holds the members `indices` of
  the RunConfig `cfg`) as the checkpoint of a single run, its seed and swept values as plain
  settings, in `out_dir`/checkpoints, with its config.json. Returns the checkpoint directory;
  `loop.extract` is the call that reads the sweep's checkpoint first."""
  if member not in indices:
    raise ValueError(f"member {member} is not in the sweep: it holds members {indices}")
  chosen = cfg.members()[member]
  agent_values = {k: v for k, v in chosen.items() if k not in ("seed", *TRAINER_DYNAMIC)}
  single = dataclasses.replace(
      cfg, seed=chosen["seed"], seeds=(), grid={}, out_dir=out_dir,
      agent_overrides={**cfg.agent_overrides, **agent_values},
      train=dataclasses.replace(cfg.train, **{k: chosen[k] for k in TRAINER_DYNAMIC
                                              if k in chosen}))
  position = indices.index(member)
  one = jax.tree.map(lambda x: x[position:position + 1], jax.device_get(state))
  target = os.path.join(out_dir, "checkpoints")
  mngr = checkpoint.manager(target)
  if mngr.all_steps():
    raise ValueError(f"{target} already holds a checkpoint; nothing was overwritten: choose "
                     "another out_dir")
  config = {**single.to_json(), "member_indices": [0]}
  checkpoint.save(mngr, one, config)
  checkpoint.finish(mngr)
  with open(os.path.join(out_dir, "config.json"), "w") as f:
    json.dump(config, f, indent=1)
  return target
