"""Learning curves from log.csv: each run's evaluation return (a sweep's, per setting: the mean
over its seeds, with the 95% interval of that mean) against env steps or wall time. A run and a
sweep draw their own at the end (curves.png); `mjx-hopper plot` draws several on one figure.

    from mjx_hopper.run import curves
    curves.plot_runs(["runs/a", "runs/b"], "runs/ab.png", x="wall_s")
"""

from __future__ import annotations

import csv
import math
import os

import numpy as np

from mjx_hopper.store.run_folder import RunFolder

X_AXES = {"env_steps": "env steps", "wall_s": "wall time (s)"}


def group_label(row: dict, grid: dict) -> str:
  """A log row's swept values as text (the CSV gives them back as strings)."""
  return " ".join(f"{name}={float(row[name]):g}" for name in grid)


def mean_interval(values) -> tuple[float, float]:
  """Mean and the half-width of its 95% interval (normal approximation; 0 for one value)."""
  values = np.asarray(values, np.float64)
  if len(values) < 2:
    return float(values.mean()), 0.0
  return float(values.mean()), float(1.96 * values.std(ddof=1) / math.sqrt(len(values)))


def evaluations(rows: list[dict], grid: dict, x: str = "env_steps") -> dict[str, np.ndarray]:
  """{setting: (evaluations, 3) rows of x, mean return, half-width of its 95% interval} of a
  run's log rows, one curve per value combination of `grid` (a single run's is labelled "").
  The wall time of an evaluation is its members' mean, counted from the run's first start:
  a resumed run's log restarts its clock, and its curve goes on from where it stopped."""
  if x not in X_AXES:
    raise ValueError(f"x takes one of {', '.join(X_AXES)}, got {x!r}")
  points: dict[str, dict[float, list[tuple[float, float]]]] = {}
  offset = last = 0.0
  for row in rows:
    wall = float(row.get("wall_s") or 0.0)
    if wall < last:  # a resumption's first row
      offset += last
    last = wall
    if row.get("kind") == "eval":
      curve = points.setdefault(group_label(row, grid), {})
      curve.setdefault(float(row["env_steps"]), []).append((offset + wall,
                                                            float(row["eval_return"])))
  out = {}
  for label, curve in points.items():
    steps = sorted(curve)
    where = steps if x == "env_steps" else [np.mean([w for w, _ in curve[s]]) for s in steps]
    out[label] = np.array([(at, *mean_interval([r for _, r in curve[s]]))
                           for at, s in zip(where, steps)])
  return out


def draw(curves: dict[str, np.ndarray], path: str, x: str = "env_steps") -> str:
  """Draws `curves` ({label: `evaluations`' rows}) with their intervals as bands to the PNG
  `path` (its folder made if missing). Returns the path."""
  from matplotlib.figure import Figure  # not pyplot: a notebook's own plots stay inline

  fig = Figure(figsize=(7, 4.5))
  ax = fig.subplots()
  for label, points in sorted(curves.items()):
    at, mean, half = points.T
    ax.plot(at, mean, label=label or "evaluation")
    ax.fill_between(at, mean - half, mean + half, alpha=0.25)
  ax.set_xlabel(X_AXES[x])
  ax.set_ylabel("evaluation return")
  ax.grid(alpha=0.3)
  ax.legend(fontsize=8)
  fig.tight_layout()
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  fig.savefig(path, dpi=100)
  return path


def plot(rows: list[dict], grid: dict, path: str, x: str = "env_steps") -> str | None:
  """A run's learning curves (`evaluations`) to the PNG `path`; None, drawing nothing, before
  its first evaluation."""
  curves = evaluations(rows, grid, x)
  return draw(curves, path, x) if curves else None


def read_run(folder: str) -> tuple[list[dict], dict]:
  """The rows of the run in `folder` (its log.csv) and its sweep's grid (config.json's; {} for
  a single run). A folder without log.csv is a FileNotFoundError naming it."""
  run = RunFolder(folder)
  if not os.path.isfile(run.log):
    raise FileNotFoundError(f"{folder} holds no log.csv: give the folder a run or sweep wrote "
                            "(its out_dir)")
  with open(run.log, newline="") as f:
    rows = list(csv.DictReader(f))
  return rows, run.grid()


def plot_runs(folders: list[str], out: str, x: str = "env_steps") -> str:
  """The learning curves of the runs (or sweeps) in `folders` on one figure, each curve
  labelled with its folder (and a sweep's setting), to the PNG `out`. Returns its path."""
  curves = {}
  for folder in folders:
    rows, grid = read_run(folder)
    mine = evaluations(rows, grid, x)
    if not mine:
      raise ValueError(f"{folder}/log.csv holds no evaluation yet")
    name = os.path.normpath(folder) if len(folders) > 1 else ""
    curves.update({f"{name} {label}".strip(): points for label, points in mine.items()})
  return draw(curves, out, x)
