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

Population-based training (`RunConfig(pbt=sweep.PBT())`, `mjx-hopper sweep --pbt`): every
`PBT.every` evaluations, the worst members take a copy of a better member's agent and perturb
the grid's settings within bounds (docs/pbt.md). A member whose learning goes non-finite is marked diverged: frozen at its
last finite agent, or under PBT, the first to be replaced.
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
from mjx_hopper.fields import check_types
from mjx_hopper.logger import RETURNS

TRAINER_DYNAMIC = ("replay_ratio",)


@dataclasses.dataclass(frozen=True)
class PBT:
  """Population-based training's choices (docs/pbt.md says why each default).

  every: evaluations (their env steps) between two exploit-and-explore steps.
  fraction: the worst `fraction` of the members (at least one), and every diverged member, each
    take a copy of the agent of a healthy member drawn from the best `fraction` (parameters,
    optimizer state, target networks, dynamic settings); each keeps its own replay, envs and
    key, but for a diverged member, whose replay and envs hold non-finite steps: it takes its
    source's too.
  factors: each of the grid's settings of a copy is multiplied by one of these, drawn at random
    (an integer setting moves at least by 1), then clipped to its bounds.
  bounds: {setting: (low, high)}; a setting not given is bounded by the grid's smallest and
    largest value.
  """

  every: int = 2
  fraction: float = 0.25
  factors: tuple[float, ...] = (0.8, 1.25)
  bounds: dict = dataclasses.field(default_factory=dict)

  def __post_init__(self):
    check_types(self)
    if not isinstance(self.every, int) or self.every < 1:
      raise ValueError(f"PBT's every must be an integer >= 1 (evaluations), got {self.every!r}")
    if not 0 < self.fraction <= 0.5:
      raise ValueError(f"PBT's fraction must be in (0, 0.5], got {self.fraction}")
    if not self.factors or any(f <= 0 for f in self.factors):
      raise ValueError(f"PBT's factors must be positive numbers, got {self.factors}")
    bounds = {}
    for name, pair in self.bounds.items():
      if (not isinstance(pair, (tuple, list)) or len(pair) != 2
          or not all(isinstance(v, (int, float)) for v in pair) or not pair[0] < pair[1]):
        raise ValueError(f"PBT's bounds for {name!r} must be (low, high) with low < high, got "
                         f"{pair!r}")
      bounds[name] = tuple(float(v) for v in pair)
    object.__setattr__(self, "bounds", bounds)

  def check(self, grid: dict, num_members: int, config_of) -> None:
    """Raises ValueError when this PBT cannot run on `grid`'s `num_members` members (per
    process): fewer than 2, nothing to perturb, a bound on an unswept setting, a bound that
    `config_of(name, value)` (which raises ValueError) refuses."""
    if num_members < 2:
      raise ValueError(f"PBT needs at least 2 members (per process), got {num_members}")
    if not grid:
      raise ValueError("PBT perturbs the grid's settings: give it at least one, such as "
                       "grid={'learning_rate': (1e-4, 1e-3)}")
    for name in self.bounds:
      if name not in grid:
        raise ValueError(f"PBT's bounds name {name!r}, which the grid does not sweep; it "
                         f"sweeps {sorted(grid)}")
    for name, (low, high) in self.ranges(grid).items():
      if low == high:
        raise ValueError(f"PBT cannot perturb {name!r}: the grid has one value, {low:g}; give "
                         "two or more, or bounds={name: (low, high)}")
      for value in (low, high):
        config_of(name, int(value) if isinstance(grid[name][0], int) else value)

  def ranges(self, grid: dict) -> dict[str, tuple[float, float]]:
    """Each swept setting's (low, high)."""
    return {name: self.bounds.get(name, (min(values), max(values)))
            for name, values in grid.items()}


def exploit_explore(pbt: PBT, returns, diverged, values: dict, ranges: dict, quanta: dict,
                    rng):
  """One PBT step over a population: (sources, new values). `returns` (S,) are the members'
  evaluations, `diverged` (S,) their marks, `values` {setting: (S,) array} their settings now.
  sources[m] is the member whose agent m takes (m itself when kept); the new values are the
  sources' perturbed (times one of `pbt.factors`, then clipped to `ranges`), the kept members'
  unchanged. A setting with a quantum ({setting: q}: 1 for an integer setting) takes multiples
  of it, and a perturbation moves it by one quantum at least.

  The members rank by return, diverged ones (and those without a finite return) last, ties to
  the lower index. Sources are drawn from the best `count` = max(1, S * fraction) that are
  healthy; the worst `count` are replaced, and every diverged member too. With no healthy
  member, nothing changes."""
  score = np.where(np.asarray(diverged) | ~np.isfinite(returns), -np.inf, returns)
  order = np.argsort(-score, kind="stable")
  count = max(1, int(len(order) * pbt.fraction))
  pool = [m for m in order[:count] if np.isfinite(score[m])]
  lost = int(np.sum(~np.isfinite(score)))
  sources = np.arange(len(order))
  new = {name: np.array(v, copy=True) for name, v in values.items()}
  for member in order[len(order) - max(count, lost) if pool else len(order):]:
    if member in pool:
      continue
    source = int(pool[rng.integers(len(pool))])
    sources[member] = source
    for name, v in values.items():
      now = float(v[source])
      moved = now * pbt.factors[rng.integers(len(pbt.factors))]
      quantum = quanta.get(name)
      if quantum:
        steps = round(moved / quantum)
        moved = quantum * (steps if steps * quantum != now else steps + np.sign(moved - now))
      new[name][member] = np.clip(moved, *ranges[name])
  return sources, new


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
      check_value(agent, preset, name, value, train_cfg, overrides)


def check_value(agent: str, preset: str, name: str, value, train_cfg: train.TrainConfig,
                overrides: dict | None = None) -> None:
  """Raises ValueError when the dynamic setting `name` cannot take `value`."""
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


def check_which(which: str) -> None:
  """Raises ValueError unless `which` names the best evaluation's agent or the latest."""
  if which not in ("best", "latest"):
    raise ValueError(f"which must be 'best' or 'latest', got {which!r}")


def member_evaluations(rows: list[dict], which: str = "best") -> dict[int, float]:
  """{member: its best (or, with which="latest", its last) evaluation's mean return} from a
  run's log rows. The best leaves out evaluations of a diverged member's frozen agent."""
  check_which(which)
  out = {}
  for row in rows:
    if row.get("kind") == "eval":
      member, value = int(row.get("member", 0)), float(row["eval_return"])
      if which == "best" and float(row.get("diverged") or 0):
        value = -np.inf  # a member that only ever diverged is listed, last
      keep = which == "latest" or member not in out or value > out[member]
      out[member] = value if keep else out[member]
  return out


def _diverged(rows: list[dict]) -> set[int]:
  """The members whose latest log row marks them diverged."""
  latest = {int(r.get("member", 0)): r for r in rows}
  return {m for m, r in latest.items() if float(r.get("diverged") or 0)}


def ranking(rows: list[dict], grid: dict, which: str = "best") -> str:
  """A table of the grid's value combinations, best first by the mean over seeds of the
  members' best evaluations (or, with which="latest", their last): mean, 95% interval of the
  mean, each seed's return, and how many of them diverged."""
  scores = member_evaluations(rows, which)
  meta = {int(r.get("member", 0)): r for r in rows if r.get("kind") == "eval"}
  diverged = _diverged(rows)
  groups: dict[str, list[tuple[float, bool]]] = {}
  for member, value in sorted(scores.items()):
    groups.setdefault(_group_label(meta[member], grid), []).append((value, member in diverged))
  lines = ["| rank | setting | mean return | 95% interval | seeds | diverged |",
           "|---|---|---|---|---|---|"]
  # Settings whose members diverged rank after the others, however their frozen agents scored.
  order = sorted(groups.items(), key=lambda kv: (np.mean([d for _, d in kv[1]]),
                                                 -np.mean([v for v, _ in kv[1]])))
  for rank, (name, entries) in enumerate(order, 1):
    mean, half = _mean_interval([v for v, _ in entries])
    lines.append(f"| {rank} | {name or '(all)'} | {mean:.1f} | ±{half:.1f} | "
                 f"{', '.join(f'{v:.0f}' for v, _ in entries)} | "
                 f"{sum(d for _, d in entries)} of {len(entries)} |")
  return "\n".join(lines)


def population_ranking(rows: list[dict], grid: dict, which: str = "best") -> str:
  """A PBT run's members, best first by their best (or latest) evaluation: each one's settings
  now, and the member it last copied from."""
  scores = member_evaluations(rows, which)
  latest = {int(r["member"]): r for r in rows if r.get("kind") == "eval"}
  diverged = _diverged(rows)
  lines = ["| rank | member | return | settings now | copied from |", "|---|---|---|---|---|"]
  order = sorted(scores.items(), key=lambda kv: (kv[0] in diverged, -kv[1]))
  for rank, (member, value) in enumerate(order, 1):
    parent = int(float(latest[member]["parent"]))
    lines.append(f"| {rank} | {member}{' (diverged)' if member in diverged else ''} | "
                 f"{value:.1f} | {_group_label(latest[member], grid)} | "
                 f"{'none' if parent == member else parent} |")
  return "\n".join(lines)


def plot(rows: list[dict], grid: dict, path: str) -> str:
  """Learning curves to a PNG: per value combination, the mean evaluation return over seeds
  against env steps, with its 95% interval as a band. Returns the path."""
  from matplotlib.figure import Figure  # not pyplot: a notebook's own plots stay inline

  curves: dict[str, dict[float, list[float]]] = {}
  for row in rows:
    if row.get("kind") == "eval":
      curve = curves.setdefault(_group_label(row, grid), {})
      curve.setdefault(float(row["env_steps"]), []).append(float(row["eval_return"]))
  fig = Figure(figsize=(7, 4.5))
  ax = fig.subplots()
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


def plot_population(rows: list[dict], grid: dict, path: str) -> str:
  """A PBT run's lineage to a PNG: the population's best, median and worst evaluation return
  against env steps, and below it each swept setting of every member. Returns the path."""
  from matplotlib.figure import Figure  # not pyplot: a notebook's own plots stay inline

  evals = [r for r in rows if r.get("kind") == "eval"]
  steps = sorted({float(r["env_steps"]) for r in evals})
  fig = Figure(figsize=(7, 3 + 2 * len(grid)))
  axes = fig.subplots(1 + len(grid), 1, sharex=True, squeeze=False)
  returns = [[float(r["eval_return"]) for r in evals if float(r["env_steps"]) == s]
             for s in steps]
  for label, stat in (("best", np.max), ("median", np.median), ("worst", np.min)):
    axes[0, 0].plot(steps, [stat(v) for v in returns], label=label)
  axes[0, 0].set_ylabel("evaluation return")
  axes[0, 0].legend(fontsize=8)
  for ax, name in zip(axes[1:, 0], grid):
    for member in sorted({int(r["member"]) for r in evals}):
      mine = [r for r in evals if int(r["member"]) == member]
      ax.plot([float(r["env_steps"]) for r in mine], [float(r[name]) for r in mine],
              drawstyle="steps-post", alpha=0.6)
    low, high = min(grid[name]), max(grid[name])
    if low > 0 and high / low >= 10:
      ax.set_yscale("log")
    ax.set_ylabel(name)
  axes[-1, 0].set_xlabel("env steps")
  for ax in axes[:, 0]:
    ax.grid(alpha=0.3)
  fig.tight_layout()
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  fig.savefig(path, dpi=100)
  return path


class Report:
  """What a run shows and keeps of its members. A single run (`single`) prints the logger's own
  lines; a sweep's rows (one per member) go to the files only, its terminal lines sum them up
  (the best member and the mean), and at the end it prints the ranking and draws the curves
  (under PBT, the population's ranking and lineage).

  It also holds each member's record, which a checkpoint keeps (`record`, `restore`): its
  settings now (a sweep's values, changed by PBT), the member it last copied from (`parents`),
  whether it diverged, and its best evaluation's return and env steps."""

  def __init__(self, grid: dict, members: list[dict], indices: list[int], say,
               single: bool, pbt: bool = False):
    self.grid, self.members, self.indices, self.say = grid, members, indices, say
    self.single, self.pbt = single, pbt
    self.last_line = -float("inf")
    self.logger_print = say if single else (lambda line: None)
    self.id_fields = () if single else ("member", *members[0])
    self.values = [dict(m) for m in members]
    self.parents = np.array(indices)
    self.diverged = np.zeros(len(members), bool)
    self.best_return = np.full(len(members), -np.inf)
    self.best_steps = np.full(len(members), -1)

  def record(self) -> dict:
    """The members' record, as JSON."""
    return {"values": self.values, "parents": self.parents.tolist(),
            "diverged": self.diverged.tolist(),
            "best_return": [None if np.isinf(v) else float(v) for v in self.best_return],
            "best_env_steps": self.best_steps.tolist()}

  def restore(self, record: dict) -> None:
    """Takes back a record that a checkpoint kept (an older checkpoint's has fewer parts). A
    single run's divergence mark is not: a run that diverges stops unsaved, so a checkpoint it
    resumes from (or a sweep's frozen member, extracted) holds a finite agent to go on from."""
    self.values = record.get("values", self.values)
    self.parents = np.array(record.get("parents", self.parents))
    if not self.single:
      self.diverged = np.array(record.get("diverged", self.diverged), bool)
    self.best_return = np.array([-np.inf if v is None else v for v in
                                 record.get("best_return", self.best_return)], np.float64)
    self.best_steps = np.array(record.get("best_env_steps", self.best_steps))

  def tags(self, m: int) -> dict:
    """The columns that name member m of this process and its state (none in a single run)."""
    if self.single:
      return {}
    parent = {"parent": int(self.parents[m])} if self.pbt else {}
    return {"member": self.indices[m], **self.values[m], **parent,
            "diverged": int(self.diverged[m])}

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
    """'best 2,480 (seed=1 learning_rate=0.0003), mean 1,920' over the finite values of the
    members that have not diverged, and how many have."""
    values = np.where(self.diverged, np.nan, np.asarray(values, np.float64))
    lost = f", {self.diverged.sum()} diverged" if self.diverged.any() else ""
    if not np.isfinite(values).any():
      return "none yet" + lost
    best = int(np.nanargmax(np.where(np.isfinite(values), values, -np.inf)))
    name = " ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                    for k, v in self.values[best].items() if k == "seed" or k in self.grid)
    return f"best {values[best]:,.1f} ({name}), mean {np.nanmean(values):,.1f}{lost}"

  def finish(self, rows: list[dict], out_dir: str) -> None:
    """A sweep's ranking and learning curves; a PBT run's ranking and lineage."""
    if self.single:
      return
    if self.pbt:
      self.say("ranking by the best evaluation:\n" + population_ranking(rows, self.grid))
      self.say(f"lineage: {plot_population(rows, self.grid, os.path.join(out_dir, 'pbt.png'))}")
    else:
      self.say("ranking by the best evaluation (mean over seeds):\n" + ranking(rows, self.grid))
      self.say(f"learning curves: {plot(rows, self.grid, os.path.join(out_dir, 'curves.png'))}")


def write_member(cfg, state, best, record: dict, indices: list[int], member: int,
                 out_dir: str) -> tuple[str, dict]:
  """Writes member `member` of a sweep's restored `state` (which holds the members `indices` of
  the RunConfig `cfg`; `best` is their agent at their best evaluations, or None; `record` their
  `Report.record()`) as the checkpoint of a single run, its seed and swept values now as plain
  settings, in `out_dir`/checkpoints, with its config.json. Returns (the checkpoint directory,
  the member's seed and swept values); `loop.extract` is the call that reads the sweep's
  checkpoint first."""
  if member not in indices:
    raise ValueError(f"member {member} is not in the sweep: it holds members {indices}")
  position = indices.index(member)
  chosen = record.get("values", [cfg.members()[i] for i in indices])[position]
  agent_values = {k: v for k, v in chosen.items() if k not in ("seed", *TRAINER_DYNAMIC)}
  single = dataclasses.replace(
      cfg, seed=chosen["seed"], seeds=(), grid={}, pbt=None, out_dir=out_dir,
      agent_overrides={**cfg.agent_overrides, **agent_values},
      train=dataclasses.replace(cfg.train, **{k: chosen[k] for k in TRAINER_DYNAMIC
                                              if k in chosen}))
  one = jax.tree.map(lambda x: x[position:position + 1], jax.device_get((state, best)))
  target = os.path.join(out_dir, "checkpoints")
  mngr = checkpoint.manager(target)
  if mngr.all_steps():
    raise ValueError(f"{target} already holds a checkpoint; nothing was overwritten: choose "
                     "another out_dir")
  mine = {k: v[position:position + 1] for k, v in record.items()}
  config = {**single.to_json(), "member_indices": [0]}
  record = {**mine, "values": [{"seed": chosen["seed"]}], "parents": [0], "diverged": [False]}
  checkpoint.save(mngr, one[0], {**config, "record": record}, best=one[1])
  checkpoint.finish(mngr)
  with open(os.path.join(out_dir, "config.json"), "w") as f:
    json.dump(config, f, indent=1)
  return target, chosen
