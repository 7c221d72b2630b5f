"""Learning curves from log.csv: the points checked against a plain loop over the rows, and
`mjx-hopper plot` on runs written by hand."""

import csv
import json
import math

import numpy as np
import pytest

from mjx_hopper.faces import cli
from mjx_hopper.run import curves


def _row(kind, env_steps, wall_s, **more):
  return {"kind": kind, "env_steps": env_steps, "wall_s": wall_s, **more}


# A sweep of two seeds for each of two learning rates, resumed once (its clock restarts).
SWEEP_ROWS = [
    _row("train", 40, 5.0),
    *[_row("eval", 40, 6.0 + m / 10, member=m, seed=m % 2, learning_rate=lr, eval_return=r)
      for m, (lr, r) in enumerate([(1e-3, 10.0), (1e-3, 14.0), (3e-4, 1.0), (3e-4, 2.0)])],
    _row("train", 80, 2.0),  # resumed
    *[_row("eval", 80, 3.0, member=m, seed=m % 2, learning_rate=lr, eval_return=r)
      for m, (lr, r) in enumerate([(1e-3, 20.0), (1e-3, 30.0), (3e-4, 4.0), (3e-4, 4.0)])],
]
GRID = {"learning_rate": [1e-3, 3e-4]}


def _reference(rows, grid, x):
  """The curves by a plain loop: per setting and evaluation, (x, mean, 1.96 * sem)."""
  out = {}
  offset, last = 0.0, 0.0
  for row in rows:
    if row["wall_s"] < last:
      offset += last
    last = row["wall_s"]
    row["clock"] = offset + row["wall_s"]
  for label in sorted({" ".join(f"{n}={r[n]:g}" for n in grid) for r in rows if r["kind"] ==
                       "eval"}):
    points = []
    for steps in sorted({r["env_steps"] for r in rows if r["kind"] == "eval"}):
      mine = [r for r in rows if r["kind"] == "eval" and r["env_steps"] == steps
              and " ".join(f"{n}={r[n]:g}" for n in grid) == label]
      values = [r["eval_return"] for r in mine]
      mean = sum(values) / len(values)
      sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))
      at = steps if x == "env_steps" else sum(r["clock"] for r in mine) / len(mine)
      points.append((at, mean, 1.96 * sd / math.sqrt(len(values))))
    out[label] = points
  return out


@pytest.mark.parametrize("x", ["env_steps", "wall_s"])
def test_a_sweeps_curves_are_each_settings_mean_over_seeds(x):
  got = curves.evaluations([dict(r) for r in SWEEP_ROWS], GRID, x)
  want = _reference([dict(r) for r in SWEEP_ROWS], GRID, x)
  assert sorted(got) == sorted(want) == ["learning_rate=0.0003", "learning_rate=0.001"]
  for label in want:
    np.testing.assert_allclose(got[label], want[label], rtol=1e-12)


def test_a_single_runs_curve_has_no_band_and_an_unknown_axis_is_refused():
  rows = [_row("eval", 40, 1.0, eval_return=5.0), _row("eval", 80, 2.0, eval_return=7.0)]
  np.testing.assert_array_equal(curves.evaluations(rows, {})[""], [[40, 5, 0], [80, 7, 0]])
  with pytest.raises(ValueError, match="x takes one of env_steps, wall_s, got 'time'"):
    curves.evaluations(rows, {}, "time")
  assert curves.plot(rows[:0], {}, "never.png") is None


def _write_run(folder, rows, grid=None):
  folder.mkdir(parents=True)
  names = sorted({k for r in rows for k in r})
  with open(folder / "log.csv", "w", newline="") as f:
    writer = csv.DictWriter(f, names)
    writer.writeheader()
    writer.writerows(rows)
  (folder / "config.json").write_text(json.dumps({"grid": grid or {}}))


def test_plot_draws_several_runs_and_a_sweep_on_one_figure(tmp_path, capsys):
  _write_run(tmp_path / "a", [_row("eval", 40, 1.0, eval_return=5.0),
                              _row("eval", 80, 2.0, eval_return=7.0)])
  _write_run(tmp_path / "sweep", SWEEP_ROWS, GRID)
  out = tmp_path / "both.png"
  cli.main(["plot", str(tmp_path / "a"), str(tmp_path / "sweep"), "--out", str(out), "--x",
            "wall_s"])
  assert capsys.readouterr().out.strip() == f"learning curves: {out}"
  assert out.stat().st_size > 10_000
  rows, grid = curves.read_run(str(tmp_path / "sweep"))
  assert grid == GRID and len(rows) == len(SWEEP_ROWS)
  cli.main(["plot", str(tmp_path / "a")])  # one run: its own folder's curves.png
  assert (tmp_path / "a" / "curves.png").stat().st_size > 10_000


def test_plot_refuses_a_folder_without_log_or_evaluations_in_one_line(tmp_path):
  (tmp_path / "empty").mkdir()
  with pytest.raises(SystemExit, match=r"^mjx-hopper plot: .*empty holds no log.csv: give the "
                                       r"folder a run or sweep wrote \(its out_dir\)$"):
    cli.main(["plot", str(tmp_path / "empty")])
  _write_run(tmp_path / "young", [_row("train", 40, 1.0)])
  with pytest.raises(SystemExit, match="young/log.csv holds no evaluation yet"):
    cli.main(["plot", str(tmp_path / "young")])
