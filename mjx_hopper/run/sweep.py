"""Batch sweeps: S members (seeds x values of dynamic settings) trained at once, as the leading
axis of one TrainState in one compiled program.

    from mjx_hopper.run import checkpoints, curves, loop, sweep
    cfg = loop.RunConfig(env="Hopper", agent="d4pg", seeds=(0, 1, 2, 3),
                         grid={"learning_rate": (1e-4, 3e-4)}, out_dir="runs/sweep")
    result = loop.run(cfg)                       # 8 members; log.csv has one row per member
    print(sweep.ranking(result.history, cfg.grid))   # loop.run prints it, and
    curves.plot(result.history, cfg.grid, "runs/sweep/curves.png")  # writes this, itself
    checkpoints.extract("runs/sweep/checkpoints", member=3, out_dir="runs/member3")

A single run is a sweep of one member (no seeds or grid). Only dynamic settings can be swept:
the agent's `Config.DYNAMIC` (learning rates, discount, n-step, sigma, vmin/vmax, MPO's
epsilons, ...) and the trainer's replay_ratio. They are arrays in the TrainState, so one
compilation serves every value. Structural settings (network sizes, atoms, samples, num_envs,
batch_size, ...) shape the program: sweeping them is refused with an error that says to run one
sweep per value.

Population-based training (`RunConfig(pbt=PBT())`, `mjx-hopper sweep --pbt`): every
`PBT.every` evaluations, the worst members take a copy of a better member's agent and perturb
the grid's settings within bounds (docs/pbt.md). A member whose learning goes non-finite is
marked diverged: frozen at its last finite agent, or under PBT, the first to be replaced.
"""

from __future__ import annotations

import os
import time

import numpy as np

from mjx_hopper.run import curves
from mjx_hopper.run.curves import group_label, mean_interval
from mjx_hopper.run.logger import RETURNS
from mjx_hopper.run.checkpoints import check_which


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
    groups.setdefault(group_label(meta[member], grid), []).append((value, member in diverged))
  lines = ["| rank | setting | mean return | 95% interval | seeds | diverged |",
           "|---|---|---|---|---|---|"]
  # Settings whose members diverged rank after the others, however their frozen agents scored.
  order = sorted(groups.items(), key=lambda kv: (np.mean([d for _, d in kv[1]]),
                                                 -np.mean([v for v, _ in kv[1]])))
  for rank, (name, entries) in enumerate(order, 1):
    mean, half = mean_interval([v for v, _ in entries])
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
                 f"{value:.1f} | {group_label(latest[member], grid)} | "
                 f"{'none' if parent == member else parent} |")
  return "\n".join(lines)


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
  """What a run shows of its members. A single run prints the logger's own lines; a sweep's
  terminal lines sum its members up (the best and the mean), and at its end it prints the
  ranking and draws the curves (under PBT, the population's ranking and lineage)."""

  def __init__(self, grid: dict, members, say):
    self.grid, self.members, self.say = grid, members, say
    self.single = members.single
    self.last_line = -float("inf")
    self.logger_print = say if self.single else (lambda line: None)
    self.id_fields = () if self.single else ("member", *members.values[0])

  def trained(self, env_steps: int, rate: float, returns, every: float) -> None:
    """A sweep's train line, every `every` seconds."""
    if not self.single and time.monotonic() - self.last_line >= every:
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
    diverged = self.members.diverged
    values = np.where(diverged, np.nan, np.asarray(values, np.float64))
    lost = f", {diverged.sum()} diverged" if diverged.any() else ""
    if not np.isfinite(values).any():
      return "none yet" + lost
    best = int(np.nanargmax(np.where(np.isfinite(values), values, -np.inf)))
    name = " ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                    for k, v in self.members.values[best].items()
                    if k == "seed" or k in self.grid)
    return f"best {values[best]:,.1f} ({name}), mean {np.nanmean(values):,.1f}{lost}"

  def summarise(self, rows: list[dict], out_dir: str) -> None:
    """The learning curves (a PBT run's lineage instead), and a sweep's ranking."""
    if self.members.pbt:
      self.say("ranking by the best evaluation:\n" + population_ranking(rows, self.grid))
      self.say(f"lineage: {plot_population(rows, self.grid, os.path.join(out_dir, 'pbt.png'))}")
      return
    if not self.single:
      self.say("ranking by the best evaluation (mean over seeds):\n" + ranking(rows, self.grid))
    path = curves.plot(rows, self.grid, os.path.join(out_dir, "curves.png"))
    if path is not None:
      self.say(f"learning curves: {path}")
